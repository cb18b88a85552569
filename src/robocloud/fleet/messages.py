"""The JSON messages between an IaaS and its robots, enough for a real robot to implement.

All messages are UTF-8 JSON objects on the keys of ``robocloud.fleet.keys``.
Fields a receiver does not know are ignored, so either side may add some.

State: each robot publishes on ``robocloud/<cloud>/robots/<id>/state`` at
least once a second, and at once on every change of its status or of its
task's phase::

    {"id": "a-0001", "cloud": "cloud-a", "kind": "tribot",
     "position": [120.0, 40.5], "speed": 1.5, "battery": 86.0, "status": "busy",
     "travel_cost_per_m": 0.05,
     "capabilities": {"grabber": {"kind": "actuating", "time": 90.0, "cost": 8.0}},
     "task": {"request_id": "r-17", "phase": "travel", "progress": 0.25,
              "capabilities": ["grabber"]},
     "seq": 1042, "sent_at": 1767225600.25}

The robot fields are MODEL.md's. ``task`` is null when the robot has none;
``phase`` is ``travel`` (driving to the location), ``work`` (using the
capabilities there), ``done`` (finished: the robot is idle at the location) or
``failed`` (it cannot finish, e.g. its battery died: status ``offline``).
``progress`` runs from 0 to 1 over the whole task, by time. A finished task
(``done`` or ``failed``) stays in ``task`` for a few seconds, then ``task`` is
null; a receiver handles it once per request. ``last_task`` (optional) keeps
the last finished task until the robot is given another, so an IaaS that was
down while the robot finished still learns how it ended. ``seq`` increases with every
message of the robot; ``sent_at`` is the robot's unix time in seconds.

Command: the IaaS sends a Zenoh query (``get``) to
``robocloud/<cloud>/robots/<id>/cmd`` whose payload is one of::

    {"type": "assign", "request_id": "r-17", "location": [400.0, 310.0],
     "capabilities": ["grabber", "light"], "execution": "parallel"}
    {"type": "cancel", "request_id": "r-17"}

On ``assign`` the robot, if idle, becomes ``busy``, drives straight to
``location`` and works there for the ``execution`` time of the capabilities
named (the longest of their times when ``parallel``, their sum when
``sequential``). On ``cancel`` it stops where it is and becomes idle.

Ack: the robot answers every command with one reply on its cmd key::

    {"ok": true, "robot": "a-0001", "request_id": "r-17", "error": null}
    {"ok": false, "robot": "a-0001", "request_id": "r-17",
     "error": "robot a-0001 is busy with request r-12."}

``ok`` is false, with a sentence in ``error``, when the robot will not do
what was asked: it is busy with another request, charging or offline, lacks
a capability, or its battery is too low for the task. An ``assign`` repeated
for the request it is already on is acknowledged again (ok). A ``cancel`` for
a request the robot is not on is ok when the robot has no task (there is
nothing to stop, so cancelling twice is harmless) and not ok when it is on
another request, so the IaaS learns its view was wrong; either way the robot
is not working on that request afterwards.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter

from robocloud.domain import Capability, Robot, RobotStatus
from robocloud.domain.robot import Finite, Name, NonNegative, Position, Speed
from robocloud.domain.task import Execution

Phase = Literal["travel", "work", "done", "failed"]
PHASES: tuple[str, ...] = ("travel", "work", "done", "failed")
FINISHED_PHASES: frozenset[str] = frozenset({"done", "failed"})

_WIRE = ConfigDict(extra="ignore", frozen=True)


class TaskProgress(BaseModel):
    """What a robot is doing for a request, inside its State."""

    model_config = _WIRE

    request_id: Name
    phase: Phase
    progress: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]
    capabilities: list[Name] = Field(description="the capabilities the robot uses for it")


class State(BaseModel):
    """A robot's report of itself: MODEL.md's robot plus its kind, task and sequence."""

    model_config = _WIRE

    id: Name
    cloud: Name
    kind: Name = Field(description='the robot type, e.g. "tribot" or "base"')
    position: Position = Field(description="[x, y] in metres")
    speed: Speed = Field(description="m/s")
    battery: Annotated[float, Field(ge=0.0, le=100.0, allow_inf_nan=False)]
    status: RobotStatus
    travel_cost_per_m: NonNegative
    capabilities: dict[Name, Capability]
    task: TaskProgress | None = None
    last_task: TaskProgress | None = Field(
        None,
        description="the robot's last finished task (phase done or failed), "
        "kept until it is given another",
    )
    seq: Annotated[int, Field(ge=0)]
    sent_at: Finite = Field(description="unix time, seconds, when the robot sent it")

    def to_robot(self, status: RobotStatus | None = None) -> Robot:
        """The MODEL.md robot this state describes, with ``status`` instead when given."""
        # Every field was validated with the same constraints Robot has.
        return Robot.model_construct(
            id=self.id,
            cloud=self.cloud,
            position=list(self.position),
            speed=self.speed,
            battery=self.battery,
            status=status or self.status,
            travel_cost_per_m=self.travel_cost_per_m,
            capabilities=dict(self.capabilities),
        )


class Assign(BaseModel):
    """Do a task: go to ``location`` and use ``capabilities`` there."""

    model_config = _WIRE

    type: Literal["assign"] = "assign"
    request_id: Name
    location: Position = Field(description="[x, y] in metres")
    capabilities: Annotated[list[Name], Field(min_length=1)]
    execution: Execution = "parallel"

    def work_time(self, capabilities: Mapping[str, Capability]) -> float:
        """Seconds of work at the location for a robot with ``capabilities`` (MODEL.md exec_i).

        Names the robot does not have count for nothing; the robot refuses
        such a command before it gets here.
        """
        times = [capabilities[name].time for name in self.capabilities if name in capabilities]
        if not times:
            return 0.0
        return max(times) if self.execution == "parallel" else sum(times)


class Cancel(BaseModel):
    """Stop working on ``request_id`` and become idle where the robot is."""

    model_config = _WIRE

    type: Literal["cancel"] = "cancel"
    request_id: Name


Command = Annotated[Assign | Cancel, Field(discriminator="type")]
COMMAND: TypeAdapter[Assign | Cancel] = TypeAdapter(Command)


class Ack(BaseModel):
    """A robot's reply to a command (and the simulator's reply to a fault)."""

    model_config = _WIRE

    ok: bool
    robot: Name
    request_id: Name | None = None
    error: str | None = Field(default=None, description="a sentence when ok is false")

    @classmethod
    def refuse(cls, robot: str, request_id: str | None, error: str) -> Ack:
        return cls(ok=False, robot=robot, request_id=request_id, error=error)
