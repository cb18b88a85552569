"""An in-memory robot link with a tiny simulation, for fast tests of the layers above.

Robots are put in with ``put``; ``assign`` and ``cancel`` answer by the same
rules as a real robot (``robocloud.fleet.behaviour``) and are recorded in
``commands``; ``step(seconds)`` moves assigned robots: straight to the
location at their speed, then work for the execution time, progress by
time, then ``done`` and idle at the location with the battery spent. Faults:
``silence`` (no more states, no answers), ``fail`` (battery dies mid-task).
Listeners are called on the caller's thread.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from robocloud.domain import Robot
from robocloud.errors import NotFound
from robocloud.fleet import behaviour
from robocloud.fleet.link import LatestStates, StateListener
from robocloud.fleet.messages import Ack, Assign, Cancel, Phase, Start, State, TaskProgress
from robocloud.selection.columns import FleetColumns


@dataclass
class _Job:
    command: Assign
    start: tuple[float, float]
    metres: float
    travel: float  # seconds
    work: float  # seconds
    elapsed: float = 0.0
    held: bool = False  # protocol 1.2: waits at the location until started


class MemoryRobotLink:
    def __init__(
        self,
        cloud: str,
        robots: Iterable[Robot | State] = (),
        offline_after: float = 5.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._cloud = cloud
        self._latest = LatestStates(cloud, offline_after, clock)
        self._jobs: dict[str, _Job] = {}
        self._silent: set[str] = set()
        self._stuck: set[str] = set()  # robots that report but do not move on
        self._seq = 0
        self.commands: list[tuple[str, Assign | Cancel | Start]] = []
        self.refusals: dict[str, str] = {}  # robot -> why its states are refused (set by tests)
        for robot in robots:
            self.put(robot)

    @property
    def cloud(self) -> str:
        return self._cloud

    # RobotLink -------------------------------------------------------------

    def robots(self) -> list[Robot]:
        return self._latest.robots()

    def states(self) -> dict[str, State]:
        return self._latest.states()

    def columns(self) -> FleetColumns:
        return self._latest.columns()

    def state(self, robot_id: str) -> State | None:
        return self._latest.state(robot_id)

    def ages(self) -> dict[str, float]:
        return self._latest.ages()

    def refused(self) -> dict[str, str]:
        return dict(self.refusals)

    def state_refusals(self) -> dict[str, int]:
        return self._latest.overtaken()

    def on_state(self, listener: StateListener) -> Callable[[], None]:
        return self._latest.add_listener(listener)

    def assign(self, robot_id: str, command: Assign) -> Ack:
        self.commands.append((robot_id, command))
        state = self._answering(robot_id)
        if state is None:
            return Ack.no_answer(robot_id, command.request_id)
        job = self._jobs.get(robot_id)
        refusal = behaviour.refuse_assign(
            robot_id,
            state.status,
            job.command.request_id if job else None,
            state.capabilities,
            state.battery,
            state.position,
            command,
        )
        if refusal is not None:
            return Ack.refuse(robot_id, command.request_id, refusal)
        if job is None:
            start = (state.position[0], state.position[1])
            metres = behaviour.distance(start, command.location)
            job = _Job(
                command,
                start,
                metres,
                metres / state.speed,
                command.work_time(state.capabilities),
                held=command.hold,
            )
            self._jobs[robot_id] = job
            self._publish(state, status="busy", task=self._progress(job, "travel"), last_task=None)
        return Ack(ok=True, robot=robot_id, request_id=command.request_id)

    def cancel(self, robot_id: str, request_id: str) -> Ack:
        self.commands.append((robot_id, Cancel(request_id=request_id)))
        state = self._answering(robot_id)
        if state is None:
            return Ack.no_answer(robot_id, request_id)
        job = self._jobs.get(robot_id)
        refusal = behaviour.refuse_cancel(
            robot_id, job.command.request_id if job else None, request_id
        )
        if refusal is not None:
            return Ack.refuse(robot_id, request_id, refusal)
        if job is not None:
            del self._jobs[robot_id]
            self._publish(state, status="idle", task=None)
        return Ack(ok=True, robot=robot_id, request_id=request_id)

    def start(self, robot_id: str, request_id: str) -> Ack:
        self.commands.append((robot_id, Start(request_id=request_id)))
        state = self._answering(robot_id)
        if state is None:
            return Ack.no_answer(robot_id, request_id)
        job = self._jobs.get(robot_id)
        if job is None or job.command.request_id != request_id:
            return Ack.refuse(robot_id, request_id, f"robot {robot_id} is not on {request_id}.")
        job.held = False
        return Ack(ok=True, robot=robot_id, request_id=request_id)

    def close(self) -> None:
        pass

    # Test controls -------------------------------------------------------------

    def put(self, robot: Robot | State, kind: str = "robot") -> State:
        """Set a robot's state as if it had just published it; returns the state kept."""
        if isinstance(robot, Robot):
            fields = robot.model_dump()
            fields["kind"] = kind
            state = State.model_validate({**fields, "task": None, "seq": 0, "sent_at": 0.0})
        else:
            state = robot
        return self._publish(state)

    def step(self, seconds: float) -> None:
        """Move the assigned robots on by ``seconds``; finished tasks leave the states."""
        for robot_id, state in self.states().items():
            if robot_id in self._silent:
                continue
            job = self._jobs.get(robot_id)
            if job is None:
                if state.task is not None:
                    self._publish(state, task=None)
                continue
            if robot_id in self._stuck:
                self._publish(state)  # it reports, its task where it was
                continue
            job.elapsed += seconds
            if job.held and job.elapsed >= job.travel:
                job.elapsed = job.travel  # there, waiting for its start
                x, y = job.command.location
                self._publish(state, position=[x, y], task=self._progress(job, "waiting"))
                continue
            if job.elapsed >= job.travel + job.work:
                del self._jobs[robot_id]
                x, y = job.command.location
                self._publish(
                    state,
                    status="idle",
                    position=[x, y],
                    battery=max(0.0, state.battery - behaviour.energy_needed(job.metres, job.work)),
                    task=self._progress(job, "done"),
                    last_task=self._progress(job, "done"),
                )
                continue
            driven = min(job.elapsed, job.travel)
            f = driven / job.travel if job.travel > 0 else 1.0
            (x0, y0), (x1, y1) = job.start, job.command.location
            # The battery is spent at the end, in one go.
            self._publish(
                state,
                position=[x0 + (x1 - x0) * f, y0 + (y1 - y0) * f],
                task=self._progress(job, "travel" if job.elapsed < job.travel else "work"),
            )

    def fail(self, robot_id: str) -> State:
        """The robot's battery dies now: offline, its task (if any) failed."""
        state = self._state(robot_id)
        job = self._jobs.pop(robot_id, None)
        task = self._progress(job, "failed") if job else None
        return self._publish(
            state, status="offline", battery=0.0, task=task, last_task=task or state.last_task
        )

    def silence(self, robot_id: str) -> None:
        """The robot stops publishing and answering; ``robots()`` shows it offline later."""
        self._state(robot_id)
        self._silent.add(robot_id)

    def stick(self, robot_id: str) -> None:
        """The robot goes on reporting, but its task stops progressing (stuck on its way)."""
        self._state(robot_id)
        self._stuck.add(robot_id)

    def recover(self, robot_id: str) -> None:
        self._silent.discard(robot_id)
        self._stuck.discard(robot_id)
        self._publish(self._state(robot_id))

    # Internals -------------------------------------------------------------

    def _state(self, robot_id: str) -> State:
        state = self.states().get(robot_id)
        if state is None:
            raise NotFound(f"there is no robot {robot_id} in {self._cloud}.", key=robot_id)
        return state

    def _answering(self, robot_id: str) -> State | None:
        if robot_id in self._silent:
            return None
        return self.states().get(robot_id)

    def _publish(self, state: State, **changes: object) -> State:
        """``state`` with ``changes`` (State fields), as the robot's next message."""
        self._seq += 1
        new = state.model_copy(update={**changes, "seq": self._seq, "sent_at": time.time()})
        self._latest.accept(new)
        return new

    @staticmethod
    def _progress(job: _Job, phase: Phase) -> TaskProgress:
        total = job.travel + job.work
        progress = 1.0 if phase == "done" else min(1.0, job.elapsed / total) if total else 0.0
        return TaskProgress(
            request_id=job.command.request_id,
            phase=phase,
            progress=progress,
            capabilities=list(job.command.capabilities),
        )
