"""The JSON messages between an IaaS and its robots, enough for a real robot to implement.

These models are the source of truth of the robot protocol (version
``PROTOCOL_VERSION``): ``robocloud.fleet.schemas`` generates the JSON Schemas
of docs/protocol/ from them, and docs/protocol.md explains them.

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

The robot fields are docs/model.md's. ``task`` is null when the robot has none;
``phase`` is ``travel`` (driving to the location), ``work`` (using the
capabilities there), ``done`` (finished: the robot is idle at the location) or
``failed`` (it cannot finish, e.g. its battery died: status ``offline``).
``progress`` runs from 0 to 1 over the whole task, by time. A finished task
(``done`` or ``failed``) stays in ``task`` for a few seconds, then ``task`` is
null; a receiver handles it once per request. ``last_task`` (optional) keeps
the last finished task until the robot is given another, so an IaaS that was
down while the robot finished still learns how it ended. ``seq`` increases with every
message of the robot; ``sent_at`` is the robot's unix time in seconds.
``State.is_newer_than`` is the one rule that orders a robot's states.

Command: the IaaS sends a Zenoh query (``get``) to
``robocloud/<cloud>/robots/<id>/cmd`` whose payload is one of::

    {"type": "assign", "request_id": "r-17", "location": [400.0, 310.0],
     "capabilities": ["grabber", "light"], "execution": "parallel"}
    {"type": "cancel", "request_id": "r-17"}

On ``assign`` the robot, if idle, becomes ``busy``, drives straight to
``location`` and works there for the ``execution`` time of the capabilities
named (the longest of their times when ``parallel``, their sum when
``sequential``). On ``cancel`` it stops where it is and becomes idle.

Protocol 1.2 adds, for robots whose state says ``"protocol": "1.2"``: an
assign with ``"hold": true`` (drive there, report phase ``waiting``, work
only after ``{"type": "start", "request_id": "r-17"}``), which is how a
mission's coalition starts together (docs/protocol.md).

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

# The robot protocol's version, MAJOR.MINOR. A new MINOR only adds optional
# fields or values a receiver may ignore; a new MAJOR changes the meaning of a
# message. It is in each schema's $id and served by the IaaS at /protocol.
PROTOCOL_VERSION = "1.2"
# Since 1.2: an assign may say ``hold`` (go, wait there for ``start``); a
# robot that understands it says ``"protocol": "1.2"`` (or later) in its state.
HOLD_SINCE = (1, 2)

Phase = Literal["travel", "waiting", "work", "done", "failed"]
PHASES: tuple[str, ...] = ("travel", "waiting", "work", "done", "failed")
FINISHED_PHASES: frozenset[str] = frozenset({"done", "failed"})

# Since 1.2: a robot's session, the id it picks each time it starts (its Zenoh session
# id): letters, digits, and . _ : - only, so it is never more than a token in a log line.
SESSION_PATTERN = r"^[0-9A-Za-z_.:-]+$"
MAX_SESSION_LENGTH = 64
# A held state counts as sent at most this long after it arrived (seconds): a state
# forged with a sent_at far ahead hides its robot about this long, not until the
# robot's clock passes it (docs/protocol.md, "seq and sent_at").
ARRIVAL_SLACK = 2.0

_WIRE = ConfigDict(extra="ignore", frozen=True)
# The fields every Robot of ``State.to_robot`` sets: one set shared by them all.
_ROBOT_FIELDS = set(Robot.model_fields)


class TaskProgress(BaseModel):
    """What a robot is doing for a request, inside its State."""

    model_config = _WIRE

    request_id: Name = Field(description="the request of the assign command")
    phase: Phase = Field(
        description="travel (driving to the location), waiting (there, held until the "
        "start command; protocol 1.2), work (using the capabilities there), "
        "done (finished, idle at the location) or failed (it cannot finish; status offline)"
    )
    progress: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] = Field(
        description="0 to 1 over the whole task (travel and work), by time"
    )
    capabilities: list[Name] = Field(description="the capabilities the robot uses for it")
    reason: Annotated[str, Field(max_length=300)] | None = Field(
        None,
        description="why the task failed, one sentence (phase failed only; protocol 1.1), "
        "carried into the request's history",
    )


class State(BaseModel):
    """A robot's report of itself: docs/model.md's robot plus its kind, task and sequence."""

    model_config = _WIRE

    id: Name = Field(description="the robot's id, as in its keys; unique in the federation")
    cloud: Name = Field(description="the robot's home cloud, as in its keys")
    kind: Name = Field(description='the robot type, free text, e.g. "tribot" or "base"')
    position: Position = Field(
        description="[x, y] in metres on the cloud's plane: one fixed origin and axes for "
        "every robot and task of the federation"
    )
    speed: Speed = Field(description="travel speed, m/s")
    battery: Annotated[float, Field(ge=0.0, le=100.0, allow_inf_nan=False)] = Field(
        description="charge left, a percent from 0 to 100 (not a fraction: 0.9 means 0.9 %)"
    )
    status: RobotStatus = Field(
        description="idle (free for a task), reserved (kept for someone else), busy (working), "
        "charging, or offline (cannot work)"
    )
    travel_cost_per_m: NonNegative = Field(description="what a metre of travel costs")
    capabilities: dict[Name, Capability] = Field(
        description="name -> {kind: sensing or actuating, time: seconds, cost}"
    )
    task: TaskProgress | None = Field(
        None, description="what the robot does for a request now, null when nothing"
    )
    last_task: TaskProgress | None = Field(
        None,
        description="the robot's last finished task (phase done or failed), "
        "kept until it is given another",
    )
    seq: Annotated[int, Field(ge=0)] = Field(
        description="increases with every state the robot sends; may start again at 0 after "
        "a restart"
    )
    sent_at: Finite = Field(description="unix time, seconds, when the robot sent it")
    protocol: Annotated[str, Field(max_length=16, pattern=r"^[0-9]+\.[0-9]+$")] | None = Field(
        None,
        description="the protocol version the robot speaks, MAJOR.MINOR (since 1.2; none: "
        "1.0 or 1.1). From 1.2 on the IaaS may send it an assign with hold and a start",
    )
    session: (
        Annotated[
            str,
            Field(min_length=1, max_length=MAX_SESSION_LENGTH, pattern=SESSION_PATTERN),
        ]
        | None
    ) = Field(
        None,
        description="since 1.2: the robot's session, an id it picks each time it starts "
        "(e.g. its Zenoh session id). States of one session are ordered by seq; a state of "
        "another session is newer only if sent later (none: one session for ever)",
    )

    def is_newer_than(self, held: State, held_until: float = float("inf")) -> bool:
        """Whether this state is newer than ``held``, the one kept for the same robot.

        Of one session (both name the same, or neither names one): a greater
        ``seq``, or a later ``sent_at`` (a robot of protocol 1.0 or 1.1 that
        restarted counts again from 0). Of another session: a later
        ``sent_at`` only, its ``seq`` being its own. ``held`` counts as sent
        no later than ``held_until`` (when it arrived plus ARRIVAL_SLACK): a
        state forged with a huge ``seq`` and a ``sent_at`` ahead is overtaken
        by the robot's next states within seconds.
        """
        held_at = min(held.sent_at, held_until)
        if self.session != held.session:
            return self.sent_at > held_at
        return self.seq > held.seq or self.sent_at > held_at

    @property
    def holds(self) -> bool:
        """Whether the robot understands an assign's ``hold`` and the ``start`` command."""
        return speaks(self.protocol, HOLD_SINCE)

    def to_robot(self, status: RobotStatus | None = None) -> Robot:
        """The docs/model.md robot this state describes, with ``status`` instead when given."""
        # Every field was validated with the same constraints Robot has. A link
        # keeps a Robot for each of its robots (100,000 of them after a full
        # listing), so nothing is copied: the Robot shares the state's
        # capabilities (robots of one kind share theirs: fleet/ingest.py) and
        # one set of field names, 1,345 -> 361 bytes a Robot (both frozen:
        # neither is ever changed).
        return Robot.model_construct(
            _ROBOT_FIELDS,
            id=self.id,
            cloud=self.cloud,
            position=self.position,
            speed=self.speed,
            battery=self.battery,
            status=status or self.status,
            travel_cost_per_m=self.travel_cost_per_m,
            capabilities=self.capabilities,
        )


class Assign(BaseModel):
    """Do a task: go to ``location`` and use ``capabilities`` there."""

    model_config = _WIRE

    type: Literal["assign"] = "assign"
    request_id: Name = Field(description="the request the task is for")
    location: Position = Field(description="[x, y] in metres, in the frame of the states")
    capabilities: Annotated[list[Name], Field(min_length=1)] = Field(
        description="the robot's capabilities to use there"
    )
    execution: Execution = Field(
        "parallel",
        description="parallel: work for the longest time of the capabilities; sequential: "
        "for the sum of their times",
    )
    hold: bool = Field(
        False,
        description="protocol 1.2: drive to the location, report phase waiting there and "
        "work only once a start command for this request came (a start that came before "
        "the robot arrived: it works on arrival). Sent only to robots whose state says "
        "protocol 1.2 or later",
    )

    def work_time(self, capabilities: Mapping[str, Capability]) -> float:
        """Seconds of work at the location for a robot with ``capabilities`` (docs/model.md exec_i).

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
    request_id: Name = Field(description="the request to stop working on")


class Start(BaseModel):
    """Protocol 1.2: begin the work of ``request_id``, held by its assign's ``hold``."""

    model_config = _WIRE

    type: Literal["start"] = "start"
    request_id: Name = Field(description="the request whose held task the robot starts")


Command = Annotated[Assign | Cancel | Start, Field(discriminator="type")]
COMMAND: TypeAdapter[Assign | Cancel | Start] = TypeAdapter(Command)


def speaks(protocol: str | None, since: tuple[int, int]) -> bool:
    """Whether a robot announcing ``protocol`` (MAJOR.MINOR, or None) speaks ``since`` or later."""
    if protocol is None:
        return False
    major, _, minor = protocol.partition(".")
    try:
        return (int(major), int(minor)) >= since and int(major) == since[0]
    except ValueError:
        return False


class Ack(BaseModel):
    """A robot's reply to a command (and the simulator's reply to a fault)."""

    model_config = _WIRE

    ok: bool = Field(description="whether the robot does what the command asks")
    robot: Name = Field(description="the robot's id")
    request_id: Name | None = Field(None, description="the command's request_id")
    error: str | None = Field(default=None, description="a sentence when ok is false")

    @classmethod
    def refuse(cls, robot: str, request_id: str | None, error: str) -> Ack:
        return cls(ok=False, robot=robot, request_id=request_id, error=error)

    @classmethod
    def no_answer(cls, robot: str, request_id: str | None, timeout: float | None = None) -> Ack:
        """What stands for the ack of a robot that did not answer within the deadline."""
        within = f" ({timeout:g} s)" if timeout is not None else ""
        return cls.refuse(robot, request_id, NO_ANSWER.format(robot=robot) + f"{within}.")

    @property
    def unanswered(self) -> bool:
        """Whether this stands for no answer at all (``no_answer``), not a refusal."""
        return not self.ok and (self.error or "").startswith(NO_ANSWER.format(robot=self.robot))


# The sentence of an ack that never came (``Ack.no_answer``); a late ack is dropped.
NO_ANSWER = "robot {robot} did not answer within the ack deadline"


# A gateway's batch (robocloud/<cloud>/fleets/<gateway>/states): a JSON array
# of States of the robots it fronts, at most this many in one message.
MAX_BATCH_STATES = 10_000
STATES: TypeAdapter[list[State]] = TypeAdapter(
    Annotated[list[State], Field(max_length=MAX_BATCH_STATES)]
)


class StateError(BaseModel):
    """The IaaS's answer to a state it could not accept, on the robot's error key.

    Published on ``robocloud/<cloud>/robots/<id>/error`` (at most once a second
    per robot); the state itself is dropped. ``field`` names the first field at
    fault the way the sentence does (``battery``, ``task.progress``).
    """

    model_config = _WIRE

    robot: Name = Field(description="the robot id of the key the state came on")
    field: str = Field(description="the first field at fault, e.g. battery or task.progress")
    error: str = Field(description="one sentence naming the field and what is wrong with it")
    protocol: str = Field(PROTOCOL_VERSION, description="the protocol version of the IaaS")
    sent_at: Finite = Field(description="unix time, seconds, when the IaaS sent it")
