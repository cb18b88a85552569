"""One AGV: its VDA 5050 messages read as a robot's State, and its robocloud order followed.

Why one long file: the AGV's state machine is one class, ``Agv``: every
message and tick of the AGV (its order, its acceptance, the reconciliation
after a restart, its liveliness) reads and moves the same state, so the
checks below are rules of that one class.

No I/O here: the gateway feeds an ``Agv`` what the broker says, under its lock,
and asks it for the robot's state and for the order of an assign.

How a VDA 5050 AGV reads as a robot (docs/protocol.md):

- ``position``: ``agvPosition`` (x, y in the project's global frame, which
  robocloud takes as the federation's frame); a visualization message updates
  it too. An AGV is a robot from its first position on.
- ``battery``: ``batteryState.batteryCharge``, a percent in VDA 5050 as here.
- ``status``: ``offline`` when its connection is OFFLINE or CONNECTIONBROKEN,
  when it has been silent longer than ``Timing.silent_after`` (its own
  messages: state, visualization, factsheet; a last will or not), with a FATAL
  error, or out of automatic mode; ``busy`` on a robocloud order or on any
  other order (nodes or edges left, an action under way); ``charging`` when
  charging; otherwise ``idle``.
- ``sent_at``: the gateway's time of the AGV's own last message, so the age a
  receiver sees is the AGV's, not the gateway's (a state is re-published, not
  renewed, while the AGV is silent).
- ``capabilities``: those of the capabilities file whose action the factsheet
  lists with scope NODE.

A robocloud task is an order ``<request>.<n>`` of two nodes (where the AGV
is, the task's location with the capabilities' actions) and the edge between.
Its phase is ``travel`` until the AGV has passed the last node, ``work`` while
the node's actions run, ``done`` once every one of them is FINISHED. It is
``failed`` when one of them FAILED, when the AGV reports a FATAL error or an
error about the order, when it drops the order for another one, or when its
connection breaks. A failed task says why (``task.reason``).

The AGV's word is checked (docs/protocol.md, "VDA 5050 fleets"):

- **Order of states.** Per connection of the AGV, a state's ``headerId`` must
  be greater and its ``timestamp`` no older than the last state taken; an
  older or repeated state is refused (``Stale``), counted, and never acted on.
  A new connection (ONLINE after OFFLINE, CONNECTIONBROKEN or nothing) starts
  the count again, as an AGV that restarted does.
- **Acceptance.** An order counts as taken once a state shows its ``orderId``
  and ``orderUpdateId``; without that within ``Timing.accept_within`` the task
  fails ("did not show the order") and the order is cancelled.
- **Reconciliation.** An AGV whose state shows a robocloud order under way
  (``<request>.<n>``) that is not its current job gets ``cancelOrder``: at once
  when the gateway sent that order since it started (its job ended: failed,
  cancelled, replaced); otherwise (an order of a gateway before a restart) it
  is adopted as the AGV's task for ``Timing.reconcile_grace`` and cancelled
  unless the IaaS assigns that request to the AGV again meanwhile. Better a
  cancel than two AGVs on one pick. Orders of another form are not the
  gateway's: the AGV is ``busy`` and left alone.
- **Liveliness.** Silent longer than ``Timing.silent_after`` (3 state
  intervals, from its factsheet's ``defaultStateInterval`` or the
  configuration, at most 30 s): ``offline``, and its task fails.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import TypeVar

from robocloud.domain import Capability, RobotStatus
from robocloud.domain.robot import MAX_COORDINATE, MAX_SPEED, MIN_SPEED, NAME_PATTERN
from robocloud.fleet.behaviour import FINISHED_LINGER, task_to_report
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

T = TypeVar("T")
CANCEL_AGAIN = 2.0  # seconds between two cancelOrders of one order the AGV keeps at
REMEMBERED = 64  # orders sent, and cancels, remembered per AGV (the newest)
UNDER_WAY = frozenset({"WAITING", "INITIALIZING", "RUNNING", "PAUSED"})
AUTOMATIC = frozenset({"AUTOMATIC", "SEMIAUTOMATIC"})
BROKEN = frozenset({"OFFLINE", "CONNECTIONBROKEN"})


class BadMessage(ValueError):
    """A message the gateway cannot use; the text is a sentence for the log."""


class Stale(BadMessage):
    """A state older than, or the same as, one already taken: ignored and counted."""


@dataclass(frozen=True)
class Timing:
    """The gateway's documented times, in seconds (``robocloud vda5050`` options)."""

    accept_within: float = 5.0  # for an AGV's state to show an order sent to it
    reconcile_grace: float = 5.0  # for the IaaS to assign again an order found on an AGV
    state_interval: float = 10.0  # an AGV's state interval when its factsheet says none
    silent_intervals: float = 3.0  # silent this many state intervals: offline
    max_silence: float = 30.0  # ... and at most this long (VDA 5050: a state every 30 s)

    def silent_after(self, interval: float | None) -> float:
        every = (
            interval if interval is not None and 0 < interval < math.inf else self.state_interval
        )
        return min(self.silent_intervals * every, self.max_silence)


def request_of(order_id: str) -> str | None:
    """The robocloud request of an order ``<request>.<n>``; None for an order of another form."""
    request, dot, n = order_id.rpartition(".")
    if not dot or not n.isdigit() or not request or len(request) > 128:
        return None
    if not re.fullmatch(NAME_PATTERN, request):
        return None
    return request


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
    sent_at: float  # monotonic, when the order was sent (or found, when adopted)
    update_id: int = 0  # the order's orderUpdateId (the gateway sends no updates)
    accepted: bool = False  # the AGV's state has shown the order
    adopted: bool = False  # found on the AGV after a restart, not sent by this gateway
    confirmed: bool = True  # an adopted order: the IaaS assigned its request again
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
    timing: Timing = field(default_factory=Timing)
    connection: str | None = None  # ONLINE, OFFLINE, CONNECTIONBROKEN; None: not heard
    vda: VdaState | None = None
    heard_at: float = -math.inf  # monotonic, the AGV's own last message
    heard_wall: float = 0.0  # unix, the same moment
    first_heard: float | None = None  # monotonic, its first state since the gateway started
    header_id: int = -1  # of the last state taken, on this connection
    header_time: float = -math.inf  # its timestamp, unix
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
    sent_orders: dict[str, None] = field(
        default_factory=dict
    )  # sent since it started, oldest first
    cancel_sent: dict[str, float] = field(default_factory=dict)  # order -> monotonic
    notes: list[str] = field(default_factory=list)  # what to log, taken by the gateway
    cancels: list[tuple[str, str]] = field(default_factory=list)  # (order, why) to send
    not_accepted: int = 0  # orders the AGV never showed (a counter, taken by the gateway)

    # -- what the broker says --------------------------------------------------------

    def on_connection(self, state: str, now: float) -> None:
        if state == self.connection:
            return
        if state == "ONLINE":
            self.header_id, self.header_time = -1, -math.inf  # a new connection counts anew
        self.connection = state
        self.dirty = True
        if state in BROKEN:
            self.offline_since = now
            if self.job is not None:
                self._finish("failed", now, f"its connection is {state}")
        else:
            self.offline_since = None

    def on_state(self, vda: VdaState, now: float, wall: float) -> None:
        sent = vda.sent_at()
        if vda.headerId <= self.header_id or sent < self.header_time:
            raise Stale(
                f"a state with headerId {vda.headerId} of {vda.timestamp_text()} is not newer "
                f"than the one taken (headerId {self.header_id}); ignored"
            )
        battery = vda.batteryState.batteryCharge
        if not 0.0 <= battery <= 100.0:
            raise BadMessage(
                f"batteryState.batteryCharge is {battery:g}, not a percent from 0 to 100"
            )
        if vda.agvPosition is not None:
            self._locate(vda.agvPosition, "agvPosition")
        before = self.status(now)
        self.vda = vda
        self.header_id, self.header_time = vda.headerId, sent
        self.heard(now, wall)
        if self.first_heard is None:
            self.first_heard = now
        if self.connection is None or self.connection in BROKEN:
            # A state is news that the AGV is online, whatever a stale retained
            # connection message said.
            self.connection, self.offline_since = "ONLINE", None
        self._follow(now)
        self._reconcile(now)
        if self.status(now) != before:
            self.dirty = True

    def on_visualization(self, position: AgvPosition | None, now: float, wall: float) -> None:
        if position is not None:
            self._locate(position, "agvPosition")
        self.heard(now, wall)

    def on_factsheet(self, factsheet: Factsheet, now: float, wall: float) -> None:
        self.factsheet = factsheet
        self.dirty = True
        self.heard(now, wall)

    def heard(self, now: float, wall: float) -> None:
        """The AGV said something itself (not its broker's last will)."""
        self.heard_at, self.heard_wall = now, wall

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
        if vda.orderId == job.order_id and vda.orderUpdateId == job.update_id:
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
        """Time passes: deadlines of the job and of the AGV's silence; progress at work."""
        job = self.job
        if job is not None:
            silent = now - self.heard_at
            if silent > self.silent_after():
                self._finish("failed", now, self._silence(silent))
                self._cancel_due(job.order_id, "it went silent", now)
            elif not job.accepted and now - job.sent_at > self.timing.accept_within:
                self.not_accepted += 1
                why = (
                    f"the AGV did not show the order {job.order_id} (orderUpdateId "
                    f"{job.update_id}) in its state within {self.timing.accept_within:g} s"
                )
                self._finish("failed", now, why)
                self._cancel_due(job.order_id, "it never showed the order", now)
            elif not job.confirmed and now - job.sent_at > self.timing.reconcile_grace:
                self._finish(
                    "failed",
                    now,
                    f"the AGV was on order {job.order_id} when the gateway started, and the "
                    f"IaaS did not assign request {job.request_id} to it again within "
                    f"{self.timing.reconcile_grace:g} s",
                )
            elif job.accepted and job.phase == "work":
                job.progress = max(job.progress, self._progress(job, now))
        self._reconcile(now)

    def silent_after(self) -> float:
        """Seconds of silence after which the AGV is offline (``Timing.silent_after``)."""
        return self.timing.silent_after(self.factsheet.state_interval() if self.factsheet else None)

    def _silence(self, silent: float) -> str:
        return (
            f"the AGV has been silent for {silent:.1f} s, over the {self.silent_after():g} s "
            "allowed"
        )

    # -- reconciliation: an order the AGV keeps, that robocloud no longer gives it ------

    def _reconcile(self, now: float) -> None:
        vda, job = self.vda, self.job
        if vda is None or not vda.orderId or not under_way(vda):
            return
        if self.connection in BROKEN or now - self.heard_at > self.silent_after():
            return  # it would not hear a cancel; its next state, if any, brings this back
        order = vda.orderId
        if job is not None and order == job.order_id:
            return
        request = request_of(order)
        if request is None:
            return  # not a robocloud order: the AGV is busy with other work
        if order in self.sent_orders:
            self._cancel_due(order, "its robocloud task is over", now)
            return
        grace_from = self.first_heard if self.first_heard is not None else now
        if now - grace_from <= self.timing.reconcile_grace and job is None:
            self._adopt(vda, order, request, now)
            return
        self._cancel_due(
            order,
            f"the IaaS did not assign request {request} to it since the gateway started",
            now,
        )

    def _adopt(self, vda: VdaState, order: str, request: str, now: float) -> None:
        """Follow an order of a gateway before a restart, until the IaaS confirms or not."""
        prefix = f"{order}-"
        actions = tuple(
            a.actionId for a in vda.actionStates if a.actionId.startswith(prefix)
            and "-cancel-" not in a.actionId
        )  # fmt: skip
        here = self.position or (0.0, 0.0)
        self.job = Job(
            request_id=request,
            order_id=order,
            capabilities=tuple(a[len(prefix) :] for a in actions),
            action_ids=actions,
            start=here,
            target=here,
            travel=0.0,
            work=0.0,
            sent_at=now,
            accepted=True,
            adopted=True,
            confirmed=False,
        )
        tail = order.rpartition(".")[2]
        self.orders = max(self.orders, int(tail))  # the next order id differs from it
        self.finished = None
        self.dirty = True
        self.notes.append(
            f"AGV {self.robot_id}: found on order {order} of request {request}, which this "
            f"gateway did not send; cancelled unless the IaaS assigns {request} to it within "
            f"{self.timing.reconcile_grace:g} s"
        )
        self._follow(now)

    def cancelling(self, order: str, now: float) -> None:
        """The gateway sends cancelOrder for ``order`` now: reconciliation need not again."""
        _remember(self.cancel_sent, order, now)

    def _cancel_due(self, order: str, why: str, now: float) -> None:
        if now - self.cancel_sent.get(order, -math.inf) < CANCEL_AGAIN:
            return
        _remember(self.cancel_sent, order, now)
        self.cancels.append((order, why))

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
        reason = None if why is None else f"AGV {self.robot_id}: {why}."[:300]
        self.finished = TaskProgress(
            request_id=job.request_id,
            phase=phase,
            progress=1.0 if phase == "done" else job.progress,
            capabilities=list(job.capabilities),
            reason=reason if phase == "failed" else None,
        )
        self.finished_until = now + FINISHED_LINGER
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
                self.job.confirmed = True  # an adopted order: the IaaS assigns it again
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
                f"{who}'s battery ({battery:.1f}%) is below the {caps.min_battery:g}% a task needs."
            )
        if self.position is None:
            return f"{who} has not reported where it is."
        return None

    def take(self, command: Assign, caps: GatewayCapabilities, now: float) -> list[NodeAction]:
        """Start the job of ``command`` (``refuse`` said yes); the actions of its last node."""
        assert self.position is not None
        shown = self.vda.orderId if self.vda is not None else ""
        if request_of(shown) == command.request_id:  # an order id is never given twice
            self.orders = max(self.orders, int(shown.rpartition(".")[2]))
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
            sent_at=now,
        )
        _remember(self.sent_orders, order_id, None)
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
        return self.finished_order if under_way(vda) else None

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
        if self.connection in BROKEN or vda is None or now - self.heard_at > self.silent_after():
            return "offline"
        if any(e.errorLevel == "FATAL" for e in vda.errors):
            return "offline"
        if vda.operatingMode not in AUTOMATIC:
            return "offline"
        if self.job is not None:
            return "busy"
        if under_way(vda):
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
        current = self.job.task() if self.job is not None else None
        task = task_to_report(current, self.finished, self.finished_until, now)
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
            sent_at=self.heard_wall,  # the AGV's last word, however often it is re-published
        )


def under_way(vda: VdaState) -> bool:
    """The AGV has an order to carry out: nodes or edges left, or an action not over."""
    return bool(vda.nodeStates or vda.edgeStates) or any(
        a.actionStatus in UNDER_WAY for a in vda.actionStates
    )


def _remember(memory: dict[str, T], key: str, value: T) -> None:
    """Keep ``key`` as the newest of ``memory``, which holds the ``REMEMBERED`` newest."""
    memory.pop(key, None)
    memory[key] = value
    while len(memory) > REMEMBERED:
        del memory[next(iter(memory))]
