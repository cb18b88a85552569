"""One NXT brick as a robot: what it reports, the task it is on, the movement under way.

Why one long file: the brick's state machine is one class, ``Brick``: each
answer, silence and command moves the same task through its movements; the
telegrams, the odometry, the battery and the link are apart already.

No I/O here: the driver (``driver.py``) feeds a ``Brick`` what the brick
answers, under the gateway's lock, asks it which movement to start and whether
to stop the motors, and carries that out over the link.

A task is a list of movements, each made when it starts (from the pose then):

1. **travel**: turn in place towards the location, then drive straight to it.
   Each is one SETOUTPUTSTATE per drive motor with a tacho limit, so the
   brick's own firmware stops the wheel at the right angle, however slow the
   link; the pose comes from the tachometers (``odometry.py``).
2. **work**: each capability's steps in order, one capability after another
   (a brick cannot do two at once, so ``parallel`` runs them in turn too):
   an arm movement to its open or close angle, a motor turned by some degrees,
   a search (drive ahead until the light sensor reads above a threshold, then
   brake), a wait.
3. **done**: the task's phase is ``done``; the brick is idle where it stands.

The brick's truth (docs/nxt.md):

- ``battery``: GETBATTERYLEVEL's millivolts through ``battery.percent``;
- ``position``: dead reckoning from the drive motors' rotation counts;
- ``status``: ``offline`` while the brick does not answer (``SILENT_AFTER``
  seconds without a reply fail its task, well within the IaaS's 5 s) and for
  ``FAULT_HOLD`` seconds after a fault; ``busy`` on a task; otherwise ``idle``;
- a motor that is driven but whose rotation count does not move for
  ``STALL_AFTER`` seconds (jammed, or its cable out) fails the task with that
  reason (``task.reason``), and the motors are braked.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from robocloud.domain import RobotStatus
from robocloud.fleet.behaviour import FINISHED_LINGER, refuse_cancel, task_to_report
from robocloud.fleet.messages import Assign, Phase, State, TaskProgress
from robocloud.gateways.nxt import battery as batteries
from robocloud.gateways.nxt.bricks import BrickConfig, Search, Step
from robocloud.gateways.nxt.odometry import Odometry
from robocloud.gateways.nxt.telegrams import OUTPUT_PORTS, RUN_IDLE, OutputState

STALL_AFTER = 1.0  # seconds a driven motor may stand still
SILENT_AFTER = 2.0  # seconds without an answer: the brick is offline, its task failed
FAULT_HOLD = 10.0  # seconds offline after a fault, then idle again (the next task may work)
AT_TARGET = 0.02  # metres: nearer than this, no travel
MAX_LEG = 1000.0  # metres of one straight movement
ARRIVE_WITHIN = 0.05  # metres: farther from the location after driving, travel again
MAX_CORRECTIONS = 2
TRAVEL = ("turn", "drive", "arrive")  # the plan's items before the capabilities' steps
TURN_AT_LEAST = math.radians(1.0)  # a smaller turn is not worth a movement
TACHO_SLACK = 1  # degrees short of a limit that count as reached
GRIP_AFTER = 0.25  # share of its closing an arm turns before a stop counts as a grip


@dataclass
class Movement:
    """One thing the brick does: motors to a tacho limit, a search, or a wait."""

    what: str  # for a reason: "turning towards the location", "closing the arm", ...
    item: str | Step  # what of the task's plan it carries out
    motors: dict[int, tuple[int, int]] = field(default_factory=dict)  # port -> power, limit
    search: Search | None = None
    wait: float = 0.0
    grips: bool = False  # an arm closing: standing still part way is holding something
    held: set[int] = field(default_factory=set)  # motors that gripped
    started_at: float | None = None  # set by the driver once the motors were told
    start_counts: dict[int, int] = field(default_factory=dict)
    moved_at: dict[int, float] = field(default_factory=dict)  # when each motor last turned
    last_counts: dict[int, int] = field(default_factory=dict)
    done: bool = False


@dataclass
class Job:
    request_id: str
    capabilities: tuple[str, ...]
    target: tuple[float, float]
    start: tuple[float, float]
    travel: float  # seconds planned
    work: float  # seconds planned
    plan: list[str | Step]  # "turn", "drive", "arrive", then the capabilities' steps
    steps_total: int
    corrections: int = 0  # travel legs again because the first did not arrive
    steps_done: int = 0
    phase: Phase = "travel"
    progress: float = 0.0

    def task(self) -> TaskProgress:
        return TaskProgress(
            request_id=self.request_id,
            phase=self.phase,
            progress=self.progress,
            capabilities=list(self.capabilities),
        )


class Brick:
    def __init__(self, robot_id: str, config: BrickConfig, min_battery: float) -> None:
        self.robot_id = robot_id
        self.config = config
        self.min_battery = min_battery
        build = config.build
        self.left = OUTPUT_PORTS[build.left]
        self.right = OUTPUT_PORTS[build.right]
        self.arm = OUTPUT_PORTS[build.arm.port] if build.arm else None
        self.odometry = Odometry(
            config.start.x,
            config.start.y,
            math.radians(config.start.heading),
            build.wheel_diameter,
            build.track_width,
        )
        self.arm_angle = float(build.arm.open) if build.arm else 0.0
        self.counts: dict[int, int] | None = None  # rotation counts last read; None: none yet
        self.pose_counts: dict[int, int] | None = None  # the counts ``odometry`` is at
        self.millivolts: int | None = None
        self.answered_at: float | None = None  # monotonic, the last reply
        self.connected = False
        self.job: Job | None = None
        self.movement: Movement | None = None
        self.stop_wanted = False
        self.finished: TaskProgress | None = None
        self.finished_until = -math.inf
        self.fault_until = -math.inf
        self.seq = 0
        self.dirty = False
        self.published_at = -math.inf
        self.notes: list[str] = []  # what to log, taken by the gateway
        self.coast: dict[int, float] = {}  # |power| -> degrees a motor turns past its limit

    # -- the link ----------------------------------------------------------------------

    def on_connected(self, now: float) -> None:
        """A (new) connection answered: counts start again from the next reading."""
        self.connected = True
        self.answered_at = now
        self._settle()  # the pose up to the last counts of the old connection
        self.counts = None
        self.pose_counts = None
        self.stop_wanted = True  # whatever it was told before the link broke, stop it
        self.dirty = True
        movement, job = self.movement, self.job
        if movement is not None and job is not None and not movement.done:
            # The link dropped for less than SILENT_AFTER: the task goes on, and the
            # movement under way starts again (braked above) from wherever it got to.
            job.plan[:0] = [*TRAVEL] if movement.item in TRAVEL else [movement.item]
            self.movement = None

    def on_answer(self, now: float) -> None:
        self.answered_at = now

    def on_silence(self, now: float) -> None:
        """No answer: after ``SILENT_AFTER`` seconds the brick is offline and its task failed."""
        if self.answered_at is not None and now - self.answered_at < SILENT_AFTER:
            return
        if self.connected:
            self.connected = False
            self.dirty = True
            self.notes.append(f"brick {self.robot_id} stopped answering")
        if self.job is not None:
            silent = now - self.answered_at if self.answered_at is not None else SILENT_AFTER
            self._finish("failed", now, f"the brick stopped answering (silent for {silent:.1f} s).")

    # -- what the brick answers ------------------------------------------------------

    def on_battery(self, millivolts: int) -> None:
        before = self.battery()
        self.millivolts = millivolts
        if before is None:
            self.dirty = True

    def on_outputs(self, states: dict[int, OutputState], now: float) -> None:
        """Rotation counts read: the pose and arm advance, the movement is judged."""
        counts = {port: s.rotation_count for port, s in states.items()}
        arm, before = self.arm, self.counts
        if arm is not None and before is not None and arm in counts and arm in before:
            self.arm_angle += counts[arm] - before[arm]
        self.counts = {**(self.counts or {}), **counts}
        if self.pose_counts is None:
            self.pose_counts = dict(self.counts)
        movement = self.movement
        if movement is None or movement.started_at is None or movement.done:
            self._settle()  # nothing is driven: the counts are at rest
            return
        finished = True
        overshoots: dict[int, int] = {}
        for port, (power, limit) in movement.motors.items():
            state = states.get(port)
            if state is None:
                finished = False
                continue
            moved = abs(state.rotation_count - movement.start_counts.get(port, 0))
            reached = moved >= limit - TACHO_SLACK or (state.run_state == RUN_IDLE and moved > 0)
            if port in movement.held:
                continue
            if reached:
                coasting = state.rotation_count != movement.last_counts.get(port)
                if state.run_state != RUN_IDLE and coasting and moved < 2 * limit + 90:
                    # Past its limit and still turning: the pose is taken once it rests.
                    movement.last_counts[port] = state.rotation_count
                    movement.moved_at[port] = now
                    finished = False
                else:
                    overshoots[abs(power)] = moved - limit
                continue
            if state.rotation_count != movement.last_counts.get(port):
                movement.last_counts[port] = state.rotation_count
                movement.moved_at[port] = now
                finished = False
                continue
            if now - movement.moved_at.get(port, movement.started_at) <= STALL_AFTER:
                finished = False
                continue
            if movement.grips and moved >= GRIP_AFTER * limit:
                # An arm closing on a ball stops short of its angle: it holds it.
                movement.held.add(port)
                self.stop_wanted = True
                self.notes.append(
                    f"brick {self.robot_id}: the arm holds something {moved} degrees into closing"
                )
                continue
            self._finish(
                "failed",
                now,
                f"motor {'ABC'[port]} stalled: it did not turn for {STALL_AFTER:g} s at power "
                f"{power} while {movement.what}.",
            )
            return
        if movement.wait and now - movement.started_at < movement.wait:
            finished = False
        if finished:
            self._settle()  # every motor at its limit: the counts are at rest
            for power, overshoot in overshoots.items():
                if 0 <= overshoot < 360:  # how far a motor coasts at that power, learned
                    learned = self.coast.get(power, float(overshoot))
                    self.coast[power] = (learned + overshoot) / 2.0
            self._movement_done(now)
        self._progress(now)

    def on_sensor(self, port: int, scaled: int, now: float) -> None:
        """A sensor read (port 0 to 3): a search ends when its light sensor reads above."""
        movement = self.movement
        if movement is None or movement.search is None or movement.done:
            return
        if port == movement.search.sensor - 1 and scaled > movement.search.above:
            self.notes.append(
                f"brick {self.robot_id}: the light sensor read {scaled} (above "
                f"{movement.search.above}): the search ends"
            )
            self.stop_wanted = True
            self._movement_done(now)

    # -- commands ----------------------------------------------------------------------

    def refuse(self, command: Assign, now: float) -> str | None:
        who = f"robot {self.robot_id}"
        if self.job is not None:
            if self.job.request_id == command.request_id:
                return None
            return f"{who} is busy with request {self.job.request_id}."
        status = self.status(now)
        if status != "idle":
            return f"{who} is {status}, not idle."
        offered = self.config.offered()
        missing = [name for name in command.capabilities if name not in offered]
        if missing:
            noun = "capability" if len(missing) == 1 else "capabilities"
            return f"{who} lacks the {noun} {', '.join(missing)}."
        battery = self.battery()
        if battery is None or battery < self.min_battery:
            shown = "unknown" if battery is None else f"{battery:.1f}%"
            return f"{who}'s battery ({shown}) is below the {self.min_battery:g}% a task needs."
        return None

    def take(self, command: Assign) -> None:
        """Start the task of ``command`` (``refuse`` said yes)."""
        if self.job is not None:
            return  # the same request again: nothing restarts
        here = self.position()
        target = (command.location[0], command.location[1])
        plan: list[str | Step] = [*TRAVEL]
        for name in command.capabilities:
            plan.extend(self.config.capabilities[name].steps)
        self.job = Job(
            request_id=command.request_id,
            capabilities=tuple(command.capabilities),
            target=target,
            start=here,
            travel=math.dist(here, target) / self.config.build.speed,
            work=command.work_time(self.config.offered()),
            plan=plan,
            steps_total=len(plan) - len(TRAVEL),
        )
        self.finished = None
        self.dirty = True

    def cancel(self, request_id: str) -> str | None:
        """Stop the task of ``request_id``: None when ok, else why not (another request)."""
        current = self.job.request_id if self.job is not None else None
        refusal = refuse_cancel(self.robot_id, current, request_id)
        if refusal is not None:
            return refusal
        if self.job is not None:
            self.job = None
            self.movement = None
            self.stop_wanted = True
            self.dirty = True
        return None

    # -- the driver asks ---------------------------------------------------------------

    def next_movement(self, now: float) -> Movement | None:
        """The movement to start now, if any (the current one when it is not started yet)."""
        if self.movement is not None and not self.movement.done:
            return self.movement if self.movement.started_at is None else None
        job = self.job
        if job is None or self.stop_wanted:
            return None
        while job.plan:
            item = job.plan.pop(0)
            if isinstance(item, str):
                movement = self._travel(item, job)
            else:
                if job.phase == "travel":
                    job.phase = "work"
                    self.dirty = True
                movement = self._step(item)
                if movement is None:  # nothing to do (the arm is there already)
                    job.steps_done += 1
            if movement is not None:
                self.movement = movement
                return movement
        if job.phase == "travel":
            job.phase = "work"
        self._finish("done", now, None)
        return None

    def started(self, movement: Movement, now: float) -> None:
        """The driver told the motors; ``start_counts`` are the counts it read just before."""
        movement.started_at = now
        for port in movement.motors:
            movement.moved_at[port] = now
            if self.counts is not None and port in self.counts:
                movement.start_counts[port] = self.counts[port]
                movement.last_counts[port] = self.counts[port]

    def _settle(self) -> None:
        """Dead reckoning up to the counts last read, taken while the wheels are at rest.

        The two wheels are read one after the other, a few milliseconds apart
        while they turn, which reads as a turn the brick did not make. Taken
        between movements, each of a constant pair of wheel speeds (a turn in
        place, a straight line), one step of ``Odometry.advance`` is exact.
        """
        if self.counts is None or self.pose_counts is None:
            return
        self.odometry.advance(*self._pending(self.counts, self.pose_counts))
        self.pose_counts = dict(self.counts)

    def _pending(self, counts: dict[int, int], since: dict[int, int]) -> tuple[int, int]:
        left, right = self.left, self.right
        return counts.get(left, 0) - since.get(left, 0), counts.get(right, 0) - since.get(right, 0)

    def position(self) -> tuple[float, float]:
        """Where the brick is: the settled pose, and what the wheels did since, in one step."""
        if self.counts is None or self.pose_counts is None:
            return self.odometry.x, self.odometry.y
        moving = replace(self.odometry)
        moving.advance(*self._pending(self.counts, self.pose_counts))
        return moving.x, moving.y

    def movement_due(self) -> bool:
        """A movement waits to be started: the driver should not sleep first."""
        if self.movement is not None:
            return self.movement.started_at is None
        return self.job is not None

    def ports_to_read(self) -> list[int]:
        ports = [self.left, self.right]
        if self.arm is not None:
            ports.append(self.arm)
        if self.movement is not None:
            ports += [p for p in self.movement.motors if p not in ports]
        return ports

    def sensor_to_read(self) -> int | None:
        movement = self.movement
        if movement is None or movement.search is None or movement.started_at is None:
            return None
        return movement.search.sensor - 1

    def stopped(self) -> None:
        self.stop_wanted = False

    # -- inside ---------------------------------------------------------------------------

    def _travel(self, item: str, job: Job) -> Movement | None:
        odo, build = self.odometry, self.config.build
        dx, dy = job.target[0] - odo.x, job.target[1] - odo.y
        distance = math.hypot(dx, dy)
        if distance < AT_TARGET:
            return None
        if item == "arrive":
            # A motor coasts past its tacho limit (a real one by some degrees): a turn
            # that overshot sends the drive off its line. Go again from where it is.
            if distance > ARRIVE_WITHIN and job.corrections < MAX_CORRECTIONS:
                job.corrections += 1
                job.plan[:0] = [*TRAVEL]
            return None
        power = build.drive_power
        if item == "turn":
            angle = math.remainder(math.atan2(dy, dx) - odo.heading, math.tau)
            if abs(angle) < TURN_AT_LEAST:
                return None
            limit = self._limit(power, odo.turn_degrees(angle))
            sign = 1 if angle > 0 else -1  # counter-clockwise: the right wheel ahead
            return Movement(
                "turning towards the location",
                item,
                motors={self.left: (-sign * power, limit), self.right: (sign * power, limit)},
            )
        if distance > MAX_LEG:  # a tacho limit is 32 bits: drive far in legs
            job.plan.insert(0, "drive")
            distance = MAX_LEG
        limit = self._limit(power, odo.degrees(distance))
        return Movement(
            "driving to the location",
            item,
            motors={self.left: (power, limit), self.right: (power, limit)},
        )

    def _step(self, step: Step) -> Movement | None:
        build = self.config.build
        if step.arm is not None:
            arm = build.arm
            assert arm is not None and self.arm is not None
            goal = arm.close if step.arm == "close" else arm.open
            delta = goal - self.arm_angle
            if abs(delta) < 1:
                return None
            power = arm.power if delta > 0 else -arm.power
            return Movement(
                f"{'closing' if step.arm == 'close' else 'opening'} the arm",
                step,
                motors={self.arm: (power, self._limit(power, abs(delta)))},
                grips=step.arm == "close",
            )
        if step.motor is not None:
            assert step.power is not None and step.degrees is not None
            return Movement(
                f"turning motor {step.motor}",
                step,
                motors={
                    OUTPUT_PORTS[step.motor]: (step.power, self._limit(step.power, step.degrees))
                },
            )
        if step.search is not None:
            power = build.drive_power
            limit = self._limit(power, self.odometry.degrees(step.search.max_distance))
            return Movement(
                "searching with the light sensor",
                step,
                motors={self.left: (power, limit), self.right: (power, limit)},
                search=step.search,
            )
        assert step.wait is not None
        return Movement("waiting", step, wait=step.wait)

    def _limit(self, power: int, degrees: float) -> int:
        """The tacho limit that turns a motor ``degrees``, less what it coasts past a limit."""
        return max(1, round(degrees - self.coast.get(abs(power), 0.0)))

    def _movement_done(self, now: float) -> None:
        movement, job = self.movement, self.job
        if movement is None:
            return
        movement.done = True
        self.movement = None
        if job is not None and job.phase == "work":
            job.steps_done += 1
        self._progress(now)

    def _progress(self, now: float) -> None:
        job = self.job
        if job is None:
            return
        total = job.travel + job.work
        travel_share = job.travel / total if total > 0 else 0.0
        if job.phase == "travel":
            whole = math.dist(job.start, job.target)
            left = math.dist(self.position(), job.target)
            covered = min(max(1.0 - left / whole, 0.0), 1.0) if whole > 0 else 1.0
            value = travel_share * covered
        else:
            share = job.steps_done / job.steps_total if job.steps_total else 1.0
            value = travel_share + (1.0 - travel_share) * min(share, 0.99)
        job.progress = max(job.progress, min(value, 0.99))

    def _finish(self, phase: Phase, now: float, reason: str | None) -> None:
        job = self.job
        if job is None:
            return
        self.finished = TaskProgress(
            request_id=job.request_id,
            phase=phase,
            progress=1.0 if phase == "done" else job.progress,
            capabilities=list(job.capabilities),
            reason=reason,
        )
        self.finished_until = now + FINISHED_LINGER
        self.job = None
        self.movement = None
        self.dirty = True
        if phase == "failed":
            self.stop_wanted = True
            self.fault_until = now + FAULT_HOLD
            self.notes.append(f"brick {self.robot_id}: request {job.request_id} failed: {reason}")

    # -- the robot it is -------------------------------------------------------------

    def battery(self) -> float | None:
        if self.millivolts is None:
            return None
        return batteries.percent(self.millivolts, self.config.battery)

    def status(self, now: float) -> RobotStatus:
        if not self.connected or now < self.fault_until:
            return "offline"
        return "busy" if self.job is not None else "idle"

    def state(self, cloud: str, now: float, wall: float) -> State | None:
        """The robot's state now (a new ``seq``), or None before the brick's first battery level."""
        battery = self.battery()
        if battery is None:
            return None
        self.seq += 1
        current = self.job.task() if self.job is not None else None
        task = task_to_report(current, self.finished, self.finished_until, now)
        return State(
            id=self.robot_id,
            cloud=cloud,
            kind=self.config.kind,
            position=list(self.position()),
            speed=self.config.build.speed,
            battery=battery,
            status=self.status(now),
            travel_cost_per_m=self.config.travel_cost_per_m,
            capabilities=self.config.offered(),
            task=task,
            last_task=self.finished,
            seq=self.seq,
            sent_at=wall,
        )
