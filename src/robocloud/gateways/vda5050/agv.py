"""One AGV: its VDA 5050 messages read as a robot's State, and its robocloud order followed.

No I/O here: the gateway feeds an ``Agv`` what the broker says, under its lock,
and asks it for the robot's state and for the order of an assign.

How a VDA 5050 AGV reads as a robot (docs/protocol.md):

- ``position``: ``agvPosition`` (x, y in the project's global frame, which
  robocloud takes as the federation's frame); a visualization message updates
  it too. An AGV is a robot from its first position on.
- ``battery``: ``batteryState.batteryCharge``, a percent in VDA 5050 as here.
- ``status``: ``offline`` when its connection is OFFLINE or CONNECTIONBROKEN,
  when it has sent no state for ``STALE_AFTER`` seconds, with a FATAL error, or
  out of automatic mode; ``busy`` on a robocloud order or on any other order
  (nodes or edges left, an action under way); ``charging`` when charging;
  otherwise ``idle``.
- ``capabilities``: those of the capabilities file whose action the factsheet
  lists with scope NODE.

A robocloud task is an order ``<request>.<n>`` of two nodes (where the AGV
is, the task's location with the capabilities' actions) and the edge between.
Its phase is ``travel`` until the AGV has passed the last node, ``work`` while
the node's actions run, ``done`` once every one of them is FINISHED. It is
``failed`` when one of them FAILED, when the AGV reports a FATAL error or an
error about the order, when it drops the order for another one, or when its
connection breaks.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from robocloud.domain import Capability, RobotStatus
from robocloud.domain.robot import MAX_COORDINATE, MAX_SPEED, MIN_SPEED, NAME_PATTERN
from robocloud.fleet.messages import Assign, Phase, State, TaskProgress
from robocloud.gateways.vda5050.capabilities import GatewayCapabilities
from robocloud.gateways.vda5050.messages import (
    AgvName,
    AgvPosition,
    Blocking,
    Factsheet,
    NodeAction,
    VdaState,
)

STALE_AFTER = 60.0  # seconds without a state (VDA 5050 asks for one at least every 30 s)
LINGER = 3.0  # seconds a finished task stays in the robot's task
UNDER_WAY = frozenset({"WAITING", "INITIALIZING", "RUNNING", "PAUSED"})
AUTOMATIC = frozenset({"AUTOMATIC", "SEMIAUTOMATIC"})
BROKEN = frozenset({"OFFLINE", "CONNECTIONBROKEN"})


class BadMessage(ValueError):
    """A message the gateway cannot use; the text is a sentence for the log."""


@dataclass
class Job:
    """The robocloud order an AGV is on."""

    request_id: str
    order_id: str
    capabilities: tuple[str, ...]
    action_ids: tuple[str, ...]
    start: tuple[float, float]
    target: tuple[float, float]
    travel: float  # seconds, expected
    work: float  # seconds, expected
    accepted: bool = False  # the AGV's state has shown the order
    work_since: float | None = None  # monotonic, when it passed the last node
    phase: Phase = "travel"
    progress: float = 0.0

    @property
    def end_node(self) -> str:
        return f"{self.order_id}-end"

    def task(self) -> TaskProgress:
        return TaskProgress(
            request_id=self.request_id,
            phase=self.phase,
            progress=self.progress,
            capabilities=list(self.capabilities),
        )


@dataclass
class Agv:
    name: AgvName
    robot_id: str
    connection: str | None = None  # ONLINE, OFFLINE, CONNECTIONBROKEN; None: not heard
    vda: VdaState | None = None
    vda_at: float = -math.inf  # monotonic
    position: tuple[float, float] | None = None
    map_id: str = ""
    factsheet: Factsheet | None = None
    factsheet_asked: float = -math.inf
    job: Job | None = None
    finished: TaskProgress | None = None
    finished_until: float = -math.inf
    failure: str | None = None  # why the last job failed, for the log
    finished_order: str | None = None  # the order of ``finished``
    seq: int = 0
    dirty: bool = False  # a change to publish now
    published_at: float = -math.inf
    offline_since: float | None = None
    orders: int = 0
    notes: list[str] = field(default_factory=list)  # what to log, taken by the gateway

    # -- what the broker says --------------------------------------------------------

    def on_connection(self, state: str, now: float) -> None:
        if state == self.connection:
            return
        self.connection = state
        self.dirty = True
        if state in BROKEN:
            self.offline_since = now
            if self.job is not None:
                self._finish("failed", now, f"its connection is {state}")
        else:
            self.offline_since = None

    def on_state(self, vda: VdaState, now: float) -> None:
        battery = vda.batteryState.batteryCharge
        if not 0.0 <= battery <= 100.0:
            raise BadMessage(
                f"batteryState.batteryCharge is {battery:g}, not a percent from 0 to 100"
            )
        if vda.agvPosition is not None:
            self._locate(vda.agvPosition, "agvPosition")
        before = self.status(now)
        self.vda, self.vda_at = vda, now
        if self.connection is None or self.connection in BROKEN:
            # A state is news that the AGV is online, whatever a stale retained
            # connection message said.
            self.connection, self.offline_since = "ONLINE", None
        self._follow(now)
        if self.status(now) != before:
            self.dirty = True

    def on_visualization(self, position: AgvPosition | None) -> None:
        if position is not None:
            self._locate(position, "agvPosition")

    def on_factsheet(self, factsheet: Factsheet) -> None:
        self.factsheet = factsheet
        self.dirty = True

    def _locate(self, position: AgvPosition, name: str) -> None:
        if not position.positionInitialized:
            return  # the AGV does not know where it is: keep the last position
        if abs(position.x) > MAX_COORDINATE or abs(position.y) > MAX_COORDINATE:
            raise BadMessage(f"{name} ({position.x:g}, {position.y:g}) is out of range")
        self.position = (position.x, position.y)
        self.map_id = position.mapId

    # -- the order ---------------------------------------------------------------------

    def _follow(self, now: float) -> None:
        job, vda = self.job, self.vda
        if job is None or vda is None:
            return
        if vda.orderId == job.order_id:
            job.accepted = True
        for error in vda.errors:
            if error.errorLevel == "FATAL" or error.refers_to("orderId", job.order_id):
                self._finish("failed", now, f"the AGV reports {error.sentence()}")
                return
        if vda.orderId != job.order_id:
            if job.accepted:
                self._finish("failed", now, f"the AGV dropped the order for {vda.orderId!r}")
            return  # not taken yet
        states = [vda.action(a) for a in job.action_ids]
        for action_id, state in zip(job.action_ids, states, strict=True):
            if state is not None and state.actionStatus == "FAILED":
                why = f": {state.resultDescription}" if state.resultDescription else ""
                self._finish("failed", now, f"its action {action_id} failed{why}")
                return
        passed = all(n.nodeId != job.end_node for n in vda.nodeStates)
        if passed and all(s is not None and s.actionStatus == "FINISHED" for s in states):
            self._finish("done", now, None)
            return
        phase: Phase = "work" if passed else "travel"
        if phase == "work" and job.work_since is None:
            job.work_since = now
        if phase != job.phase:
            job.phase = phase
            self.dirty = True
        job.progress = max(job.progress, self._progress(job, now))

    def tick(self, now: float) -> None:
        """Time passes: a job at work progresses by time between two states of the AGV."""
        job = self.job
        if job is not None and job.accepted and job.phase == "work":
            job.progress = max(job.progress, self._progress(job, now))

    def _progress(self, job: Job, now: float) -> float:
        total = job.travel + job.work
        travel_share = job.travel / total if total > 0 else 0.0
        if job.phase == "travel":
            whole = math.dist(job.start, job.target)
            here = self.position or job.start
            covered = 1.0 - math.dist(here, job.target) / whole if whole > 0 else 1.0
            return travel_share * min(max(covered, 0.0), 1.0)
        since = now - (job.work_since if job.work_since is not None else now)
        worked = min(0.99, since / job.work) if job.work > 0 else 0.99
        return min(1.0, travel_share + (1.0 - travel_share) * worked)

    def _finish(self, phase: Phase, now: float, why: str | None) -> None:
        job = self.job
        assert job is not None
        self.finished = TaskProgress(
            request_id=job.request_id,
            phase=phase,
            progress=1.0 if phase == "done" else job.progress,
            capabilities=list(job.capabilities),
        )
        self.finished_until = now + LINGER
        self.finished_order = job.order_id
        self.job = None
        self.failure = why
        self.dirty = True
        if why is not None:
            self.notes.append(f"AGV {self.robot_id}: request {job.request_id} failed: {why}")

    def rejection(self, order_id: str) -> str | None:
        """Why the AGV refused ``order_id``, if its state says so."""
        if self.job is None and self.finished is not None and self.failure is not None:
            return self.failure
        vda = self.vda
        if vda is None:
            return None
        for error in vda.errors:
            if error.refers_to("orderId", order_id):
                return f"the AGV reports {error.sentence()}"
        return None

    def refuse(self, command: Assign, caps: GatewayCapabilities, now: float) -> str | None:
        """Why the AGV cannot take ``command``; None when it can (or is on it already)."""
        who = f"AGV {self.robot_id}"
        if self.job is not None:
            if self.job.request_id == command.request_id:
                return None
            return f"{who} is busy with request {self.job.request_id}."
        status = self.status(now)
        if status != "idle":
            return f"{who} is {status}, not idle."
        offered = self.capabilities(caps)
        missing = [name for name in command.capabilities if name not in offered]
        if missing:
            noun = "capability" if len(missing) == 1 else "capabilities"
            return f"{who} lacks the {noun} {', '.join(missing)}."
        assert self.vda is not None
        battery = self.vda.batteryState.batteryCharge
        if battery < caps.min_battery:
            return (
                f"{who}'s battery ({battery:.1f}%) is below the {caps.min_battery:g}% "
                "a task needs."
            )
        if self.position is None:
            return f"{who} has not reported where it is."
        return None

    def take(self, command: Assign, caps: GatewayCapabilities, now: float) -> list[NodeAction]:
        """Start the job of ``command`` (``refuse`` said yes); the actions of its last node."""
        assert self.position is not None
        self.orders += 1
        order_id = f"{command.request_id}.{self.orders}"
        # Parallel: the actions run together, not while driving; sequential: one at a time.
        blocking: Blocking = "SOFT" if command.execution == "parallel" else "HARD"
        actions = [
            NodeAction(
                caps.capabilities[name].action,
                f"{order_id}-{name}",
                blocking,
                [p.model_dump(mode="json") for p in caps.capabilities[name].parameters],
            )
            for name in command.capabilities
        ]
        offered = self.capabilities(caps)
        target = (command.location[0], command.location[1])
        self.job = Job(
            request_id=command.request_id,
            order_id=order_id,
            capabilities=tuple(command.capabilities),
            action_ids=tuple(a.action_id for a in actions),
            start=self.position,
            target=target,
            travel=math.dist(self.position, target) / self.speed(caps),
            work=command.work_time(offered),
        )
        self.finished = None
        self.failure = None
        self.dirty = True
        return actions

    def cancel(self) -> Job | None:
        """Drop the job (the gateway sends cancelOrder); the robot reports no task at once."""
        job, self.job = self.job, None
        if job is not None:
            self.dirty = True
        return job

    def still_running(self, request_id: str) -> str | None:
        """The order of a failed task of ``request_id`` the AGV still runs, if any.

        A task fails on what the AGV reports (an action failed, a fault); the
        AGV may hold the order all the same, so a cancel must still reach it.
        """
        vda, finished = self.vda, self.finished
        if vda is None or finished is None or finished.request_id != request_id:
            return None
        if vda.orderId != self.finished_order:
            return None
        under_way = any(a.actionStatus in UNDER_WAY for a in vda.actionStates)
        return self.finished_order if vda.nodeStates or vda.edgeStates or under_way else None

    # -- the robot it is ---------------------------------------------------------------

    def capabilities(self, caps: GatewayCapabilities) -> dict[str, Capability]:
        if self.factsheet is None:
            return {}
        return caps.offered(self.factsheet.node_actions())

    def speed(self, caps: GatewayCapabilities) -> float:
        sheet = self.factsheet
        top = sheet.physicalParameters.speedMax if sheet and sheet.physicalParameters else None
        if top is None or not top > 0:
            return caps.speed
        return min(max(top, MIN_SPEED), MAX_SPEED)

    def status(self, now: float) -> RobotStatus:
        vda = self.vda
        if self.connection in BROKEN or vda is None or now - self.vda_at > STALE_AFTER:
            return "offline"
        if any(e.errorLevel == "FATAL" for e in vda.errors):
            return "offline"
        if vda.operatingMode not in AUTOMATIC:
            return "offline"
        if self.job is not None:
            return "busy"
        if vda.nodeStates or vda.edgeStates or any(
            a.actionStatus in UNDER_WAY for a in vda.actionStates
        ):
            return "busy"
        if vda.batteryState.charging:
            return "charging"
        return "idle"

    def kind(self) -> str:
        sheet = self.factsheet
        series = sheet.typeSpecification.seriesName if sheet and sheet.typeSpecification else ""
        if series and len(series) <= 128 and re.fullmatch(NAME_PATTERN, series):
            return series
        return "agv"

    def state(self, cloud: str, caps: GatewayCapabilities, now: float, wall: float) -> State | None:
        """The robot's state message now (a new ``seq``), or None before its first position."""
        if self.position is None or self.vda is None:
            return None
        self.seq += 1
        task = self.job.task() if self.job is not None else None
        if task is None and self.finished is not None and now < self.finished_until:
            task = self.finished
        return State(
            id=self.robot_id,
            cloud=cloud,
            kind=self.kind(),
            position=[self.position[0], self.position[1]],
            speed=self.speed(caps),
            battery=self.vda.batteryState.batteryCharge,
            status=self.status(now),
            travel_cost_per_m=caps.travel_cost_per_m,
            capabilities=self.capabilities(caps),
            task=task,
            last_task=self.finished,
            seq=self.seq,
            sent_at=wall,
        )
