"""One simulated robot: kinematics, battery and the task state machine, without I/O.

::

    idle --assign--> busy: travel --arrived--> busy: work --finished--> idle (task done)
                       |          |                ^  |
                       |          '--(hold)--> waiting |   (protocol 1.2: until start)
                       +--- battery empty --------+--> offline (task failed)
    busy --cancel--> idle, where it stands

A task's robot drives straight to the location at its speed, then works for
the execution time of the capabilities it was told to use (docs/model.md's
exec_i); progress runs from 0 to 1 over the whole task, by time. Battery
follows ``robocloud.fleet.behaviour``. Besides tasks, a robot may be in a
background activity (another user's job, charging, maintenance) that the
fleet's churn starts and that ends on its own.

Time here is simulated seconds; ``now`` is the wall clock (unix seconds)
that stamps the states.
"""

from __future__ import annotations

import secrets
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import msgspec

from robocloud.domain import Capability, Robot, RobotStatus
from robocloud.fleet.behaviour import (
    DRAIN_PER_M,
    DRAIN_PER_S,
    distance,
    refuse_assign,
    refuse_cancel,
)
from robocloud.fleet.ingest import WireState, WireTask, wire_task
from robocloud.fleet.messages import (
    PROTOCOL_VERSION,
    Ack,
    Assign,
    Phase,
    State,
    TaskProgress,
)

# A finished task stays in the robot's state this long (wall seconds), so one
# lost message does not hide how it ended.
FINISHED_LINGER = 3.0
# The kind follows the actuator, as in the thesis's NXT prototype.
KIND_BY_ACTUATOR = {"grabber": "tribot", "kicker": "base"}
_EPSILON = 1e-9


# The robots' session (protocol 1.2): they all start with the simulator's process, so a
# restarted simulator's robots start an order of their own (State.is_newer_than).
SESSION = secrets.token_hex(8)


@dataclass
class Job:
    """A task the robot is doing for a request."""

    request_id: str
    capabilities: tuple[str, ...]
    target: tuple[float, float]
    travel_left: float  # metres
    work_left: float  # seconds
    total: float  # seconds, travel and work
    elapsed: float = 0.0
    held: bool = False  # protocol 1.2: waits at the location until started

    @property
    def phase(self) -> Phase:
        if self.travel_left > 0.0:
            return "travel"
        return "waiting" if self.held else "work"

    @property
    def progress(self) -> float:
        return min(1.0, self.elapsed / self.total) if self.total > 0.0 else 0.0


@dataclass
class Background:
    """Something else the robot is doing: ``status`` for ``remaining`` seconds."""

    status: RobotStatus
    remaining: float  # seconds; float('inf') for as long as the simulation runs
    battery_rate: float = 0.0  # percent per second, negative when it drains


class SimRobot:
    def __init__(self, robot: Robot, kind: str) -> None:
        self.id = robot.id
        self.cloud = robot.cloud
        self.kind = kind
        self.position: tuple[float, float] = (robot.position[0], robot.position[1])
        self.speed = robot.speed
        self.battery = robot.battery
        self.status: RobotStatus = robot.status
        self.travel_cost_per_m = robot.travel_cost_per_m
        self.capabilities: dict[str, Capability] = dict(robot.capabilities)
        self.job: Job | None = None
        self.background: Background | None = None
        self.finished: TaskProgress | None = None
        self.finished_until = 0.0
        self.silent = False
        self.seq = 0
        # Set when a command or a fault changed the robot between ticks.
        self.dirty = False
        self._capabilities_json: msgspec.Raw | None = None  # made once, for wire_state

    @classmethod
    def from_json(cls, data: Mapping[str, Any] | Robot) -> SimRobot:
        """A robot from a docs/model.md robot (a dict may add ``kind``)."""
        if isinstance(data, Robot):
            return cls(data, _kind_of(data))
        fields = dict(data)
        kind = fields.pop("kind", None)
        robot = Robot.model_validate(fields)
        return cls(robot, str(kind) if kind else _kind_of(robot))

    @property
    def dead(self) -> bool:
        return self.status == "offline" and self.battery <= 0.0

    @property
    def available(self) -> bool:
        """Idle with nothing going on: the churn may start an activity."""
        return self.status == "idle" and self.job is None and self.background is None

    def wire_state(self, now: float) -> WireState:
        """``state(now)`` as a gateway writes it (msgspec, no validation: the robot is valid)."""
        self.seq += 1
        task: WireTask | None = None
        if self.job is not None:
            job = self.job
            task = WireTask(job.request_id, job.phase, job.progress, list(job.capabilities))
        elif self.finished is not None and now < self.finished_until:
            task = wire_task(self.finished)
        if self._capabilities_json is None:
            self._capabilities_json = msgspec.Raw(
                msgspec.json.encode({n: c.model_dump() for n, c in self.capabilities.items()})
            )
        return WireState(
            id=self.id,
            cloud=self.cloud,
            kind=self.kind,
            position=[self.position[0], self.position[1]],
            speed=self.speed,
            battery=self.battery,
            status=self.status,
            travel_cost_per_m=self.travel_cost_per_m,
            capabilities=self._capabilities_json,
            task=task,
            last_task=wire_task(self.finished),
            seq=self.seq,
            sent_at=now,
            protocol=PROTOCOL_VERSION,
            session=SESSION,
        )

    def state(self, now: float) -> State:
        """The robot's state message, stamped ``now``; each call is a new message."""
        self.seq += 1
        task: TaskProgress | None = None
        if self.job is not None:
            task = TaskProgress(
                request_id=self.job.request_id,
                phase=self.job.phase,
                progress=self.job.progress,
                capabilities=list(self.job.capabilities),
            )
        elif self.finished is not None and now < self.finished_until:
            task = self.finished
        return State(
            id=self.id,
            cloud=self.cloud,
            kind=self.kind,
            position=[self.position[0], self.position[1]],
            speed=self.speed,
            battery=self.battery,
            status=self.status,
            travel_cost_per_m=self.travel_cost_per_m,
            capabilities=self.capabilities,
            task=task,
            last_task=self.finished,
            seq=self.seq,
            sent_at=now,
            protocol=PROTOCOL_VERSION,
            session=SESSION,
        )

    # Commands -------------------------------------------------------------

    def assign(self, command: Assign) -> Ack:
        current = self.job.request_id if self.job is not None else None
        refusal = refuse_assign(
            self.id,
            self.status,
            current,
            self.capabilities,
            self.battery,
            self.position,
            command,
        )
        if refusal is not None:
            return Ack.refuse(self.id, command.request_id, refusal)
        if current is None:
            target = (command.location[0], command.location[1])
            metres = distance(self.position, target)
            work = command.work_time(self.capabilities)
            self.job = Job(
                request_id=command.request_id,
                capabilities=tuple(command.capabilities),
                target=target,
                travel_left=metres,
                work_left=work,
                total=metres / self.speed + work,
                held=command.hold,
            )
            self.status = "busy"
            self.finished = None
            self.dirty = True
        return Ack(ok=True, robot=self.id, request_id=command.request_id)

    def start(self, request_id: str) -> Ack:
        """Protocol 1.2: work on the held task of ``request_id`` (on arrival, if not there yet)."""
        current = self.job.request_id if self.job is not None else None
        if current != request_id:
            doing = f"on request {current}" if current is not None else "on no request"
            return Ack.refuse(
                self.id, request_id, f"robot {self.id} is {doing}, not on request {request_id}."
            )
        assert self.job is not None
        if self.job.held:
            self.job.held = False
            self.dirty = self.job.travel_left == 0.0  # waiting -> work: a new phase now
        return Ack(ok=True, robot=self.id, request_id=request_id)

    def cancel(self, request_id: str) -> Ack:
        current = self.job.request_id if self.job is not None else None
        refusal = refuse_cancel(self.id, current, request_id)
        if refusal is not None:
            return Ack.refuse(self.id, request_id, refusal)
        if current is not None:
            self.job = None
            self.status = "idle"
            self.dirty = True
        return Ack(ok=True, robot=self.id, request_id=request_id)

    # Faults -------------------------------------------------------------

    def kill_battery(self, now: float) -> None:
        """The battery dies now: the robot stops, offline, its task failed."""
        self.battery = 0.0
        self._die(now)

    def start_background(self, activity: Background) -> None:
        self.background = activity
        self.status = activity.status
        self.dirty = True

    # Time -------------------------------------------------------------

    def advance(self, dt: float, now: float) -> list[State]:
        """Run ``dt`` simulated seconds; a state for each change of status or phase.

        A long ``dt`` (a high speedup) may cross several phases; each is
        reported, in order.
        """
        changes: list[State] = []
        if self.job is not None:
            self._advance_job(dt, now, changes)
        elif self.background is not None:
            self._advance_background(dt, now, changes)
        return changes

    def _advance_job(self, dt: float, now: float, changes: list[State]) -> None:
        job = self.job
        assert job is not None
        while dt > _EPSILON and self.job is job:
            if job.travel_left > 0.0:
                metres = min(job.travel_left, self.speed * dt)
                empty = self.battery / DRAIN_PER_M < metres
                if empty:
                    metres = self.battery / DRAIN_PER_M
                self._move_towards(job.target, metres)
                job.travel_left -= metres
                job.elapsed += metres / self.speed
                dt -= metres / self.speed
                self.battery = max(0.0, self.battery - metres * DRAIN_PER_M)
                if empty:
                    self._die(now)
                    changes.append(self.state(now))
                    return
                if job.travel_left <= _EPSILON:
                    # Land exactly, so the robot ends where it was sent.
                    job.travel_left = 0.0
                    self.position = job.target
                    changes.append(self.state(now))
            elif job.held:
                return  # there, waiting for its start: time passes, nothing moves
            else:
                seconds = min(job.work_left, dt)
                empty = self.battery / DRAIN_PER_S < seconds
                if empty:
                    seconds = self.battery / DRAIN_PER_S
                job.work_left -= seconds
                job.elapsed += seconds
                dt -= seconds
                self.battery = max(0.0, self.battery - seconds * DRAIN_PER_S)
                if empty:
                    self._die(now)
                    changes.append(self.state(now))
                    return
                if job.work_left <= _EPSILON:
                    self._finish(job, "done", now)
                    changes.append(self.state(now))
                    return
        there = self.job is job and job.travel_left == 0.0 and not job.held
        if there and job.work_left <= _EPSILON:
            # Already there with nothing to do (or dt too short to notice): done.
            self._finish(job, "done", now)
            changes.append(self.state(now))

    def _advance_background(self, dt: float, now: float, changes: list[State]) -> None:
        activity = self.background
        assert activity is not None
        seconds = min(dt, activity.remaining)
        self.battery = min(100.0, max(0.0, self.battery + activity.battery_rate * seconds))
        activity.remaining -= seconds
        if activity.remaining <= _EPSILON:
            self.background = None
            self.status = "idle"
            changes.append(self.state(now))

    def _move_towards(self, target: tuple[float, float], metres: float) -> None:
        x, y = self.position
        left = distance(self.position, target)
        if left <= metres or left == 0.0:
            self.position = target
            return
        f = metres / left
        self.position = (x + (target[0] - x) * f, y + (target[1] - y) * f)

    def _finish(self, job: Job, phase: Phase, now: float) -> None:
        self.finished = TaskProgress(
            request_id=job.request_id,
            phase=phase,
            progress=1.0 if phase == "done" else job.progress,
            capabilities=list(job.capabilities),
        )
        self.finished_until = now + FINISHED_LINGER
        self.job = None
        self.status = "idle" if phase == "done" else "offline"

    def _die(self, now: float) -> None:
        self.battery = 0.0
        self.background = None
        if self.job is not None:
            self._finish(self.job, "failed", now)
        self.status = "offline"
        self.dirty = True


def _kind_of(robot: Robot) -> str:
    for actuator, kind in KIND_BY_ACTUATOR.items():
        if actuator in robot.capabilities:
            return kind
    return "robot"
