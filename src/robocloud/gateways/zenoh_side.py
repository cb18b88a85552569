"""A gateway's robots on Zenoh, either way docs/protocol.md allows; shared by every gateway.

- ``ZenohRobots``: for each robot (an AGV, a brick, a ROS 2 robot) a command
  queryable and a state publisher, the keys of any robot.
- ``ZenohFleet``: as a fleet gateway ("Fleet gateways"): a command queryable
  per robot it fronts, and their states on the gateway's batch key
  (``--gateway-name NAME`` of ``robocloud vda5050``, ``robocloud nxt``,
  ``robocloud ros2``).

Either is all a gateway knows of Zenoh, on one Zenoh client session.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Callable
from typing import Protocol

import pydantic
import zenoh

from robocloud.errors import describe_validation_errors
from robocloud.fleet import keys
from robocloud.fleet.ingest import encode_batch
from robocloud.fleet.messages import COMMAND, Ack, Assign, Cancel, Start, State

log = logging.getLogger(__name__)

CommandHandler = Callable[[str, Assign | Cancel], Ack]
_JSON = zenoh.Encoding.APPLICATION_JSON


class RobotSide(Protocol):
    """What the gateway needs of the Zenoh side; ``ZenohRobots`` is the one there is."""

    @property
    def cloud(self) -> str: ...

    def has(self, robot: str) -> bool: ...

    def add(self, robot: str) -> None: ...

    def remove(self, robot: str) -> None: ...

    def publish(self, state: State) -> None: ...

    def close(self) -> None: ...


class ZenohRobots:
    """Robots of ``cloud`` on ``session``; each command goes to ``on_command(robot, command)``."""

    def __init__(self, session: zenoh.Session, cloud: str, on_command: CommandHandler) -> None:
        self._session = session
        self._cloud = keys.check_chunk(cloud, "cloud")
        self._on_command = on_command
        self._lock = threading.Lock()
        self._robots: dict[str, tuple[zenoh.Queryable[None], zenoh.Publisher]] = {}

    @property
    def cloud(self) -> str:
        return self._cloud

    def has(self, robot: str) -> bool:
        with self._lock:
            return robot in self._robots

    def add(self, robot: str) -> None:
        """Declare the robot: its cmd queryable, then its state publisher."""
        with self._lock:
            if robot in self._robots:
                return
            queryable = self._session.declare_queryable(
                keys.cmd_key(self._cloud, robot), lambda query: self._answer(robot, query)
            )
            publisher = self._session.declare_publisher(
                keys.state_key(self._cloud, robot), encoding=_JSON
            )
            self._robots[robot] = (queryable, publisher)

    def remove(self, robot: str) -> None:
        with self._lock:
            declared = self._robots.pop(robot, None)
        if declared is not None:
            for entity in declared:
                with contextlib.suppress(zenoh.ZError):
                    entity.undeclare()  # type: ignore[no-untyped-call]

    def publish(self, state: State) -> None:
        with self._lock:
            declared = self._robots.get(state.id)
        if declared is not None:
            declared[1].put(state.model_dump_json())

    def close(self) -> None:
        with self._lock:
            robots = list(self._robots)
        for robot in robots:
            self.remove(robot)

    def _answer(self, robot: str, query: zenoh.Query) -> None:
        with query:
            _reply(self._cloud, robot, query, self._on_command)


class ZenohFleet:
    """The robots of ``cloud`` behind one gateway named ``name``, on its batch key.

    Each state is published as it comes, as a batch of one on the gateway's
    batch key (a gateway's fleet is small; what it saves is a publisher per
    robot). Commands come on each robot's own command key, a queryable per
    robot: a gateway with a certificate of its own (``<cloud>-gateway-<name>``)
    may declare only its robots' keys, not the wildcard ``robots/*/cmd``.
    """

    def __init__(
        self, session: zenoh.Session, cloud: str, name: str, on_command: CommandHandler
    ) -> None:
        self._session = session
        self._cloud = keys.check_chunk(cloud, "cloud")
        self._on_command = on_command
        self._lock = threading.Lock()
        self._robots: dict[str, zenoh.Queryable[None]] = {}
        self._publisher = session.declare_publisher(keys.batch_key(cloud, name), encoding=_JSON)

    @property
    def cloud(self) -> str:
        return self._cloud

    def has(self, robot: str) -> bool:
        with self._lock:
            return robot in self._robots

    def add(self, robot: str) -> None:
        with self._lock:
            if robot in self._robots:
                return
            self._robots[robot] = self._session.declare_queryable(
                keys.cmd_key(self._cloud, robot), lambda query: self._answer(robot, query)
            )

    def remove(self, robot: str) -> None:
        with self._lock:
            queryable = self._robots.pop(robot, None)
        if queryable is not None:
            with contextlib.suppress(zenoh.ZError):
                queryable.undeclare()  # type: ignore[no-untyped-call]

    def publish(self, state: State) -> None:
        if self.has(state.id):
            self._publisher.put(encode_batch([state.model_dump(mode="json")]))

    def close(self) -> None:
        with self._lock:
            robots = list(self._robots)
        for robot in robots:
            self.remove(robot)
        with contextlib.suppress(zenoh.ZError):
            self._publisher.undeclare()  # type: ignore[no-untyped-call]

    def _answer(self, robot: str, query: zenoh.Query) -> None:
        with query:
            _reply(self._cloud, robot, query, self._on_command)


def _reply(cloud: str, robot: str, query: zenoh.Query, on_command: CommandHandler) -> None:
    """Answer a command query for ``robot`` with its Ack (the caller finalizes the query)."""
    payload = query.payload.to_bytes() if query.payload is not None else b""
    try:
        command = COMMAND.validate_json(payload)
    except pydantic.ValidationError as error:
        sentence = describe_validation_errors(error.errors(), prefix="command").message
        ack = Ack.refuse(robot, None, sentence)
    else:
        if isinstance(command, Start):  # the gateways speak protocol 1.1: no held tasks
            ack = Ack.refuse(robot, command.request_id, f"robot {robot} does not hold tasks "
                             "(protocol 1.1): it has no start command.")
            query.reply(keys.cmd_key(cloud, robot), ack.model_dump_json(), encoding=_JSON)
            return
        try:
            ack = on_command(robot, command)
        except Exception as error:  # the gateway must answer, whatever happened
            log.exception("the command %s for %s failed", command.type, robot)
            ack = Ack.refuse(robot, command.request_id, f"the gateway failed: {error}")
    query.reply(keys.cmd_key(cloud, robot), ack.model_dump_json(), encoding=_JSON)
