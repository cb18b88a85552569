"""One ROS 2 robot: what its topics and Nav2 say, read as a robot's State; its task followed.

No I/O here: the gateway feeds a ``RosRobot`` what the robot's Zenoh session
hears, under its lock, and asks it for the State and for what to send.

How a Nav2 robot reads as a robot (docs/ros2.md has the table):

- ``position``: ``base_frame`` in ``map_frame`` from ``/tf`` (map -> odom ->
  base_link), else ``/amcl_pose``, placed in the cloud's frame by the file's
  ``offset``.
- ``battery``: ``sensor_msgs/BatteryState.percentage`` x 100; ``charging``
  when ``power_supply_status`` is CHARGING.
- ``status``: ``offline`` while its action server is not visible or a message
  did not decode for its distro (``fault``); ``busy`` on a robocloud task or
  while Nav2 runs another user's goal; ``charging``; otherwise ``idle``.

A task is a NavigateToPose goal to the location (in ``map_frame``), then a
dwell of the capabilities' time. Its phase is ``travel`` until the goal
succeeds, then ``work``, then ``done``. It is ``failed``, with a reason, when
Nav2 rejects or aborts the goal, another goal preempts it, or the action
server vanishes; progress runs by time, from the feedback's
``estimated_time_remaining`` (``distance_remaining / speed`` without one).
"""

from __future__ import annotations

import math
import secrets
from collections import deque
from dataclasses import dataclass, field

from robocloud.domain import RobotStatus
from robocloud.fleet.behaviour import FINISHED_LINGER, refuse_cancel, task_to_report
from robocloud.fleet.messages import Assign, Phase, State, TaskProgress
from robocloud.gateways.ros2 import interfaces as ros
from robocloud.gateways.ros2.robots_file import RobotEntry

STALE_AFTER = 5.0  # seconds without tf or battery before the robot counts as offline
# Seconds an aborted goal waits for the status that shows a preempting goal: Nav2 aborts
# a preempted goal, and its result and its status may come in either order.
PREEMPT_GRACE = 0.5
ACTIVE = frozenset({ros.STATUS_ACCEPTED, ros.STATUS_EXECUTING, ros.STATUS_CANCELING})


@dataclass
class Job:
    request_id: str
    goal_id: bytes
    capabilities: tuple[str, ...]
    target: tuple[float, float]  # cloud frame
    goal_map: tuple[float, float]  # the robot's map frame
    work: float  # seconds of dwell at the goal
    started: float  # monotonic
    travel_eta: float  # seconds, expected, updated by feedback
    phase: Phase = "travel"
    progress: float = 0.0
    accepted: bool = False
    work_since: float | None = None
    sent: bool = False
    aborted: tuple[str, float] | None = None  # (detail, when): an abort not yet explained

    def task(self) -> TaskProgress:
        return TaskProgress(
            request_id=self.request_id,
            phase=self.phase,
            progress=self.progress,
            capabilities=list(self.capabilities),
        )


@dataclass
class RosRobot:
    robot_id: str
    entry: RobotEntry
    frames: dict[str, tuple[str, float, float, float]] = field(default_factory=dict)
    amcl: tuple[float, float] | None = None  # /amcl_pose in the map frame: the fallback
    battery: float | None = None
    charging: bool = False
    heard_at: float = -math.inf
    server_up: bool = False
    fault: str | None = None  # why it cannot be chosen: a message its distro does not decode
    others_active: frozenset[bytes] = frozenset()  # goals of other users Nav2 runs
    own_goals: deque[bytes] = field(default_factory=lambda: deque(maxlen=64))  # ours, recent
    job: Job | None = None
    finished: TaskProgress | None = None
    finished_until: float = -math.inf
    seq: int = 0
    dirty: bool = False
    published_at: float = -math.inf
    notes: list[str] = field(default_factory=list)  # warnings to log, taken by the gateway
    events: list[str] = field(default_factory=list)  # news to log, taken by the gateway
    cancels: list[bytes] = field(default_factory=list)  # goals to cancel, taken by the gateway

    # -- what the robot says --------------------------------------------------------

    def on_transforms(
        self, transforms: list[tuple[str, str, float, float, float]], now: float
    ) -> None:
        """``(parent, child, x, y, yaw)`` of each transform of a TFMessage."""
        for parent, child, x, y, yaw in transforms:
            self.frames[child.lstrip("/")] = (parent.lstrip("/"), x, y, yaw)
        self.heard_at = now

    def on_amcl(self, frame: str, x: float, y: float, now: float) -> None:
        """``/amcl_pose``: where the robot is when ``/tf`` gives no map frame."""
        if frame.lstrip("/") == self.entry.map_frame and math.isfinite(x) and math.isfinite(y):
            self.amcl = (x, y)

    def on_battery(self, percentage: float, power_supply_status: int, now: float) -> None:
        if not math.isfinite(percentage) or not 0.0 <= percentage <= 1.0:
            self.notes.append(
                f"robot {self.robot_id}: ignoring BatteryState.percentage {percentage:g}, "
                "not a fraction from 0 to 1"
            )
            return
        before = self.charging
        self.battery = percentage * 100.0
        self.charging = power_supply_status == ros.POWER_CHARGING
        self.heard_at = now
        if before != self.charging:
            self.dirty = True

    def on_server(self, up: bool, now: float, why: str) -> None:
        """The action server appeared or vanished (liveliness, or a queryable matched)."""
        if up == self.server_up:
            return
        self.server_up = up
        self.dirty = True
        (self.events if up else self.notes).append(
            f"robot {self.robot_id}: Nav2's action server {self.entry.action} is "
            f"{'visible' if up else 'gone'} ({why})"
        )
        if not up and self.job is not None and self.job.sent:
            self._finish("failed", now, f"Nav2's action server {self.entry.action} vanished.")

    def on_fault(self, reason: str, now: float) -> None:
        """A message that does not decode for the robot's distro: it cannot be chosen."""
        if self.fault is not None:
            return  # the first reason says it; the others would only repeat it
        self.fault = reason
        self.dirty = True
        self.notes.append(f"robot {self.robot_id} is not selectable: {reason}")
        if self.job is not None:
            if self.job.sent and self.server_up:
                self.cancels.append(self.job.goal_id)  # the robot must not go on for it
            self._finish("failed", now, reason)

    def on_feedback(self, goal_id: bytes, distance: float, eta: float, now: float) -> None:
        job = self.job
        if job is None or goal_id != job.goal_id or job.phase != "travel":
            return
        job.accepted = True
        if eta > 0 and math.isfinite(eta):
            remaining = eta
        elif math.isfinite(distance) and distance >= 0:
            remaining = distance / self.entry.speed
        else:
            return
        job.travel_eta = (now - job.started) + remaining
        self._progress(job, now)

    def on_status(self, statuses: list[tuple[bytes, int]], now: float) -> None:
        """A GoalStatusArray: whose goals Nav2 runs, and how ours is doing."""
        ours = self.job.goal_id if self.job is not None else None
        # A goal of ours canceled a moment ago may show active until Nav2 has stopped it.
        mine_before = set(self.own_goals)
        others = frozenset(
            g for g, s in statuses if s in ACTIVE and g != ours and g not in mine_before
        )
        if others != self.others_active:
            self.others_active = others
            self.dirty = True
        job = self.job
        if job is None or not job.sent:
            return
        mine = [s for g, s in statuses if g == job.goal_id]
        if mine and mine[-1] in ACTIVE:
            job.accepted = True
        if (
            others
            and job.phase == "travel"
            and job.accepted
            and (not mine or mine[-1] not in ACTIVE)
        ):
            other = next(iter(others)).hex()
            self._finish("failed", now, f"navigation preempted by another goal ({other}).")

    def on_goal_response(self, goal_id: bytes, accepted: bool, now: float) -> None:
        job = self.job
        if job is None or goal_id != job.goal_id:
            return
        if not accepted:
            self._finish("failed", now, "Nav2 rejected the goal.")
        else:
            job.accepted = True

    def on_result(self, goal_id: bytes, status: int, detail: str, now: float) -> None:
        """The held get_result answered: the goal ended with ``status``."""
        job = self.job
        if job is None or goal_id != job.goal_id or job.phase != "travel":
            return
        if status == ros.STATUS_SUCCEEDED:
            job.phase, job.work_since = "work", now
            job.travel_eta = now - job.started
            self.dirty = True
            self.tick(now)
            return
        name = ros.STATUS_NAMES.get(status, f"status {status}")
        if status == ros.STATUS_ABORTED and self.others_active:
            why = f"navigation preempted by another goal ({next(iter(self.others_active)).hex()})."
        elif status == ros.STATUS_ABORTED and job.aborted is None:
            job.aborted = (detail, now)  # preempted or not: the status will tell
            return
        elif status == ros.STATUS_CANCELED:
            why = "navigation canceled on the robot, not by robocloud."
        else:
            why = f"navigation {name}{': ' + detail if detail else ''}."
        self._finish("failed", now, why)

    def on_result_lost(self, goal_id: bytes, now: float) -> None:
        """The held get_result ended without a reply: the action server went away."""
        job = self.job
        if job is None or goal_id != job.goal_id or job.phase != "travel":
            return
        self.server_up = False
        self.dirty = True
        self.notes.append(
            f"robot {self.robot_id}: get_result ended without a reply; Nav2's action "
            f"server {self.entry.action} counts as gone"
        )
        self._finish("failed", now, f"Nav2's action server {self.entry.action} vanished.")

    # -- time ------------------------------------------------------------------------

    def tick(self, now: float) -> None:
        job = self.job
        if job is None:
            return
        if job.aborted is not None and now - job.aborted[1] >= PREEMPT_GRACE:
            detail = job.aborted[0]
            self._finish("failed", now, f"navigation aborted{': ' + detail if detail else ''}.")
            return
        if job.phase == "work" and job.work_since is not None and now - job.work_since >= job.work:
            self._finish("done", now, None)
            return
        self._progress(job, now)

    def _progress(self, job: Job, now: float) -> None:
        total = job.travel_eta + job.work
        if job.phase == "travel":
            share = (now - job.started) / total if total > 0 else 0.0
        else:
            done = now - (job.work_since or now)
            share = (job.travel_eta + done) / total if total > 0 else 1.0
        job.progress = max(job.progress, min(0.99, max(0.0, share)))

    def _finish(self, phase: Phase, now: float, why: str | None) -> None:
        job = self.job
        assert job is not None
        self.finished = TaskProgress(
            request_id=job.request_id,
            phase=phase,
            progress=1.0 if phase == "done" else job.progress,
            capabilities=list(job.capabilities),
            reason=why[:300] if why is not None else None,
        )
        self.finished_until = now + FINISHED_LINGER
        self.job = None
        self.dirty = True
        if why is not None:
            self.notes.append(f"robot {self.robot_id}: request {job.request_id} failed: {why}")

    # -- commands --------------------------------------------------------------------

    def refuse(self, command: Assign, min_battery: float, now: float) -> str | None:
        who = f"robot {self.robot_id}"
        if self.job is not None:
            if self.job.request_id == command.request_id:
                return None
            return f"{who} is busy with request {self.job.request_id}."
        status = self.status(now)
        if status != "idle":
            return f"{who} is {status}, not idle{self._why_not(now)}."
        missing = [n for n in command.capabilities if n not in self.entry.capabilities]
        if missing:
            noun = "capability" if len(missing) == 1 else "capabilities"
            return f"{who} lacks the {noun} {', '.join(missing)}."
        assert self.battery is not None
        if self.battery < min_battery:
            return (
                f"{who}'s battery ({self.battery:.1f}%) is below the {min_battery:g}% a task needs."
            )
        return None

    def _why_not(self, now: float) -> str:
        if self.fault is not None:
            return f": {self.fault.rstrip('.')}"
        if not self.server_up:
            return f": Nav2's action server {self.entry.action} is not visible"
        if self.others_active:
            return ": Nav2 runs another user's goal"
        return ""

    def take(self, command: Assign, now: float) -> Job:
        """Start the job of ``command`` (``refuse`` said yes): a new goal id, not sent yet."""
        here = self.position()
        assert here is not None
        target = (command.location[0], command.location[1])
        job = Job(
            request_id=command.request_id,
            goal_id=secrets.token_bytes(16),
            capabilities=tuple(command.capabilities),
            target=target,
            goal_map=self.entry.offset.to_map(*target),
            work=command.work_time(self.entry.capabilities),
            started=now,
            travel_eta=math.dist(here, target) / self.entry.speed,
        )
        self.job, self.finished = job, None
        self.own_goals.append(job.goal_id)
        self.dirty = True
        return job

    def cancel(self, request_id: str) -> tuple[str | None, Job | None]:
        """``(refusal, the job to cancel on the robot)``; the robot reports no task at once."""
        current = self.job.request_id if self.job is not None else None
        refusal = refuse_cancel(self.robot_id, current, request_id)
        if refusal is not None:
            return refusal, None
        job, self.job = self.job, None
        if job is not None:
            self.dirty = True
        return None, job

    # -- the robot it is -------------------------------------------------------------

    def position(self) -> tuple[float, float] | None:
        """``base_frame`` in ``map_frame`` through ``/tf`` (else ``/amcl_pose``), in the cloud's."""
        e = self.entry
        x, y, yaw, frame, hops = 0.0, 0.0, 0.0, e.base_frame, 0
        while frame != e.map_frame:
            link = self.frames.get(frame)
            hops += 1
            if link is None or hops > 8:
                if self.amcl is None:
                    return None
                x, y = self.amcl  # no map frame on /tf: AMCL's estimate
                break
            parent, px, py, pyaw = link
            c, s = math.cos(pyaw), math.sin(pyaw)
            x, y, yaw = px + c * x - s * y, py + s * x + c * y, pyaw + yaw
            frame = parent
        cx, cy = e.offset.to_cloud(x, y)
        if abs(cx) > 1e7 or abs(cy) > 1e7:
            return None
        return cx, cy

    def status(self, now: float) -> RobotStatus:
        if self.fault is not None or not self.server_up or now - self.heard_at > STALE_AFTER:
            return "offline"
        if self.job is not None or self.others_active:
            return "busy"
        if self.charging:
            return "charging"
        return "idle"

    def missing(self) -> str | None:
        """What the robot has not said yet that it needs to be listed, or None."""
        e = self.entry
        if self.position() is None:
            return (f"no {e.base_frame} in {e.map_frame} on /{e.tf_topic} yet "
                    f"({e.map_frame} -> {e.odom_frame} -> {e.base_frame}), "
                    f"nor /{e.amcl_topic}")  # fmt: skip
        if self.battery is None:
            return f"no battery on /{e.battery_topic} yet"
        return None

    def state(self, cloud: str, cost_per_m: float, now: float, wall: float) -> State | None:
        """The robot's State now (a new ``seq``), or None before it has a pose and a battery."""
        here = self.position()
        if here is None or self.battery is None:
            return None
        self.seq += 1
        current = self.job.task() if self.job is not None else None
        task = task_to_report(current, self.finished, self.finished_until, now)
        return State(
            id=self.robot_id,
            cloud=cloud,
            kind=self.entry.kind,
            position=[here[0], here[1]],
            speed=self.entry.speed,
            battery=self.battery,
            status=self.status(now),
            travel_cost_per_m=cost_per_m,
            capabilities=dict(self.entry.capabilities),
            task=task,
            last_task=self.finished,
            seq=self.seq,
            sent_at=wall,
        )
