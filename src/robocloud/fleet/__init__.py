"""The robots of one cloud: their live state and the commands they take (the gateway).

``RobotLink`` is the seam; ``ZenohRobotLink`` is the real one and
``MemoryRobotLink`` the one for tests. The messages are in ``messages``.
"""

from robocloud.fleet.link import RobotLink, ZenohRobotLink
from robocloud.fleet.memory import MemoryRobotLink
from robocloud.fleet.messages import Ack, Assign, Cancel, State, TaskProgress
from robocloud.fleet.zenoh_session import open_client, open_router, wait_for_liveliness

__all__ = [
    "Ack",
    "Assign",
    "Cancel",
    "MemoryRobotLink",
    "RobotLink",
    "State",
    "TaskProgress",
    "ZenohRobotLink",
    "open_client",
    "open_router",
    "wait_for_liveliness",
]
