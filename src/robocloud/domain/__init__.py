"""Robots, capabilities, tasks and coalitions: pure data and rules, no I/O."""

from robocloud.domain.coalition import Coalition
from robocloud.domain.request import (
    ACTIVE_STATES,
    FINAL_STATES,
    REQUEST_STATES,
    RequestState,
    can_move,
    is_final,
)
from robocloud.domain.robot import (
    ROBOT_STATUSES,
    Capability,
    CapabilityLike,
    Robot,
    RobotLike,
    RobotStatus,
)
from robocloud.domain.task import CRITERIA_IMPORTANCE, Task

__all__ = [
    "ACTIVE_STATES",
    "CRITERIA_IMPORTANCE",
    "FINAL_STATES",
    "REQUEST_STATES",
    "ROBOT_STATUSES",
    "Capability",
    "CapabilityLike",
    "Coalition",
    "RequestState",
    "Robot",
    "RobotLike",
    "RobotStatus",
    "Task",
    "can_move",
    "is_final",
]
