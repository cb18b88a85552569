"""The life of one request, as a pure function: ``decide(life, event, now) -> (life, effects)``.

Like h11's HTTP state machine, this module does no I/O. The request's actor
(``robocloud.iaas.actor``) feeds it events (a selection's result, the robots'
acknowledgements and reports, a clock tick, the application's cancel) and
carries out the effects it returns, in order (commit a state, reserve robots,
command them, follow them). So every rule of the life cycle is here, and it is
tested as a table, without sockets.

::

    received -> selecting -> dispatched -> underway -> completed
                    |             |            |
                    v             v            v
                 rejected       failed       failed          (any of them) -> canceled

Inside ``selecting`` (and while a failed robot is replaced) an **attempt** runs
three stages, each an effect whose result comes back as an event::

    Select --Selected--> Reserve --Reserved--> Assign --Acked--> dispatched
       ^                    | taken                | refused or no answer
       '--------------------'-----------------------'  (excluding those robots, at most
                                                        ``Rules.attempts`` times)

Dispatch and the replacement of a failed robot are the same attempt, for the
whole task or for the capabilities the failed robots brought.

The rules that keep robots honest:

- A robot that does not acknowledge ``ok`` (it refused, or did not answer in
  time) is told to stop at once: a late robot must not work unreserved.
- A robot that fails (its battery died, it went offline, it was silent for
  ``offline_after`` seconds, it dropped the request) is told to stop, released
  and replaced within what is left of the task's cost, time and robot count.
- The watchdog: a robot past its expected finish (its t_i from when it was
  sent, plus ``Rules.tolerance`` of it), or that reports no progress for
  ``stall_after`` seconds while it travels or works, has failed: it is told
  to stop and replaced. Progress a robot reports extends nothing. A request
  is never dispatched or underway past its ``max_time`` plus the tolerance of
  it (robot time, under the simulator's speed-up): it fails, every robot
  told to stop.
- Each robot's failure is reported (``RobotFailed``, with its cause), and
  each part done (``RobotDone``): the supervisor counts them and sets aside
  robots that keep failing (``robocloud.iaas.routes``).
- A robot's report of its ``last_task`` counts: a robot that finished while
  this IaaS was down is done, not failed.
- A final state never changes; the results of an attempt that arrive after it
  (a late reservation, late acknowledgements) only release and stop robots.

Why one long file: every rule of a request's life is in ``decide`` and its
handlers, pure and tested as one table; cut in two, a rule would be read in
one file and its exception in the other.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any, Literal

from robocloud.domain import FINAL_STATES, Task

Pairs = tuple[tuple[str, str], ...]  # (robot id, its cloud)
# Why a robot failed its part (``RobotFailed``; the metrics count them by cause).
Cause = Literal[
    "no_ack", "overrun", "stalled", "offline", "silent", "reported", "dropped", "loan_ended"
]
CAUSES: tuple[str, ...] = (
    "no_ack", "overrun", "stalled", "offline", "silent", "reported", "dropped", "loan_ended",
)
# The causes that count against a robot (two in a row set it aside): the robot's
# own doing, not a loan's end or a battery that died.
STRIKING: frozenset[str] = frozenset({"no_ack", "overrun", "stalled"})
Purpose = Literal["dispatch", "replace"]
Stage = Literal["selecting", "reserving", "assigning"]


@dataclass(frozen=True)
class Now:
    """The clocks at an event: ``mono`` for durations, ``wall`` (unix seconds) to store."""

    mono: float
    wall: float


@dataclass(frozen=True)
class Rules:
    offline_after: float = 5.0  # seconds of silence before a working robot has failed
    attempts: int = 8  # selections per dispatch or replacement when robots are taken or refuse
    time_scale: float = 1.0  # robot seconds per wall second (the simulator's speedup)
    # After a restart of the IaaS its robots must first reconnect (a Zenoh client
    # retries every 1 to 4 s): none is counted silent before this many seconds.
    restart_grace: float = 10.0
    # The watchdog (docs/model.md, "After dispatch"): a robot may take its t_i
    # plus the larger of ``overrun_ratio`` of it and ``overrun_min`` seconds of
    # the wall clock. The floor is wall time: a robot that does not follow the
    # simulator's speed-up (a real AGV beside simulated robots), and the
    # network's own delays, are not scaled.
    overrun_ratio: float = 0.5
    overrun_min: float = 30.0
    # Seconds (wall clock) without progress while travelling or working: stalled.
    stall_after: float = 30.0
    # A robot heard again after this much silence (a gateway that restarted, a
    # link that came back) is sent its assign again: idempotent for a robot on
    # the task, and what a restarted gateway needs to keep the robot's order.
    remind_after: float = 2.0

    def tolerance(self, expected: float) -> float:
        """Wall seconds a robot (or a request) may run past ``expected`` robot seconds."""
        return max(self.overrun_ratio * expected / self.time_scale, self.overrun_min)

    def due(self, start_wall: float, expected: float) -> float:
        """The wall time past which something started at ``start_wall`` has overrun."""
        return start_wall + expected / self.time_scale + self.tolerance(expected)

    def failure(
        self,
        silent: float,
        started_wall: float | None,
        expected: float,
        now_wall: float,
        still: float | None,
        what: str = "finish",
    ) -> tuple[Cause, str] | None:
        """The watchdog's rule for one robot, of a request or a mission: whether it failed.

        ``silent``: seconds since it was last heard; ``started_wall``: when it
        began what it should end within ``expected`` robot seconds (None: not
        begun); ``still``: seconds since its progress last grew while it
        travels or works (None: neither). Silent past ``offline_after``, then
        past ``due``, then no progress for ``stall_after``.
        """
        if silent > self.offline_after:
            return "silent", f"it has been silent for {silent:.0f} s"
        if started_wall is not None:
            due = self.due(started_wall, expected)
            if now_wall > due:
                return "overrun", (
                    f"it is past its expected {what} ({expected:.0f} s robot time, plus "
                    f"{self.tolerance(expected):.0f} s of tolerance) by {now_wall - due:.0f} s"
                )
        if still is not None and still > self.stall_after:
            return "stalled", f"it reported no progress for {still:.0f} s (stalled)"
        return None


@dataclass(frozen=True)
class Member:
    """One robot of the coalition (or of an attempt), as the request follows it."""

    robot: str
    cloud: str
    capabilities: tuple[str, ...]
    time: float  # t_i, robot seconds from its own dispatch
    cost: float  # c_i
    offset: float = 0.0  # robot seconds from the request's dispatch to this robot's
    phase: str = "pending"  # pending, travel, work, done
    progress: float = 0.0
    since: float = 0.0  # monotonic: when the request began to follow it
    heard_at: float = 0.0  # monotonic: its latest report (or ``since``)
    confirmed: bool = False  # it has reported working on this request
    progressed_at: float = 0.0  # monotonic: when its progress last grew (or ``since``)

    @property
    def pair(self) -> tuple[str, str]:
        return (self.robot, self.cloud)

    def to_json(self) -> dict[str, Any]:
        return {
            "robot": self.robot,
            "cloud": self.cloud,
            "capabilities": list(self.capabilities),
            "time": self.time,
            "cost": self.cost,
            "offset": self.offset,
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Member:
        return cls(
            robot=str(data["robot"]),
            cloud=str(data["cloud"]),
            capabilities=tuple(data.get("capabilities", ())),
            time=float(data.get("time", 0.0)),
            cost=float(data.get("cost", 0.0)),
            offset=float(data.get("offset", 0.0)),
        )


@dataclass(frozen=True)
class Attempt:
    """One try at choosing, reserving and commanding robots."""

    purpose: Purpose
    number: int
    task: Task  # the whole task, or what the failed robots leave missing
    stage: Stage = "selecting"
    chosen: tuple[Member, ...] = ()
    selection: Mapping[str, Any] = field(default_factory=dict)  # what the selection found
    replacing: tuple[str, ...] = ()  # the failed robots this attempt replaces

    @property
    def pairs(self) -> Pairs:
        return tuple(m.pair for m in self.chosen)


@dataclass(frozen=True)
class Life:
    """What the actor knows of its request between two events."""

    request_id: str
    task: Task
    rules: Rules = Rules()
    state: str = "received"  # as stored
    members: Mapping[str, Member] = field(default_factory=dict)  # the dispatched coalition
    attempt: Attempt | None = None
    excluded: frozenset[str] = frozenset()  # robots this request will not choose again
    selection: Mapping[str, Any] = field(default_factory=dict)  # as stored
    dispatched_at: float | None = None  # wall clock
    failed: tuple[str, ...] = ()  # failed robots whose replacement has not started
    resumed: bool = False  # a restart of the IaaS found it dispatched

    @property
    def final(self) -> bool:
        return self.state in FINAL_STATES

    def followed(self) -> tuple[Member, ...]:
        """Every robot the request follows: its coalition and the robots of a commanded attempt."""
        robots = list(self.members.values())
        if self.attempt is not None and self.attempt.stage == "assigning":
            robots += [m for m in self.attempt.chosen if m.robot not in self.members]
        return tuple(robots)


# -- events ---------------------------------------------------------------------


@dataclass(frozen=True)
class Start:
    """The actor begins: a new request, or one a restart found unfinished."""

    resumed: bool = False


@dataclass(frozen=True)
class Selected:
    """The result of ``Select``: the chosen robots, or None and the reason."""

    chosen: tuple[Member, ...] | None
    selection: Mapping[str, Any]
    reason: str | None = None
    notes: tuple[str, ...] = ()  # what gathering the robots noticed (a cloud left out)
    # False when the search was cut (its time budget, its worker stopped): with
    # nothing chosen, the task was not shown infeasible, so the request fails
    # rather than being rejected.
    complete: bool = True


@dataclass(frozen=True)
class Reserved:
    """The result of ``Reserve``: the robots another request holds (then none is held)."""

    taken: tuple[str, ...] = ()


@dataclass(frozen=True)
class Acked:
    """The result of ``Assign``: robot -> why, for each robot that did not acknowledge ok.

    ``unanswered``: those of them that gave no answer within the ack deadline.
    """

    refused: Mapping[str, str] = field(default_factory=dict)
    unanswered: frozenset[str] = frozenset()


@dataclass(frozen=True)
class RobotReport:
    """A state message of a followed robot, read for this request.

    ``phase`` is its task's phase when the task is this request's, else None;
    ``last_phase`` the phase of its last finished task when that was this request.
    """

    robot: str
    status: str
    battery: float
    phase: str | None = None
    progress: float = 0.0
    last_phase: str | None = None
    reason: str | None = None  # why its task failed, when it says (protocol 1.1)


@dataclass(frozen=True)
class Tick:
    """Time passes (the actor sends one about twice a second)."""


@dataclass(frozen=True)
class CancelAsked:
    """The application cancels the request."""


@dataclass(frozen=True)
class LoanEnded:
    """A robot's home ended its loan to this request (e.g. this cloud was unreachable)."""

    robot: str
    home: str
    why: str


@dataclass(frozen=True)
class Crashed:
    """The actor hit an error it cannot carry on from."""

    reason: str


Event = Start | Selected | Reserved | Acked | RobotReport | Tick | CancelAsked | LoanEnded | Crashed


# -- effects ----------------------------------------------------------------------


@dataclass(frozen=True)
class Commit:
    """Move the stored request to ``state`` (then tell whoever follows it)."""

    state: str
    reason: str | None = None
    detail: str | None = None
    selection: Mapping[str, Any] | None = None


@dataclass(frozen=True)
class Note:
    """Add an event to the request's history."""

    detail: str


@dataclass(frozen=True)
class SaveSelection:
    selection: Mapping[str, Any]


@dataclass(frozen=True)
class Publish:
    """Tell the request's followers it changed (live progress; nothing to store)."""


@dataclass(frozen=True)
class Select:
    """Choose a coalition for ``task`` among the robots in view, but ``exclude``; -> Selected."""

    task: Task
    exclude: frozenset[str]
    offset: float = 0.0  # robot seconds since the request's dispatch (for replacements)
    attempt: int = 1


@dataclass(frozen=True)
class Reserve:
    """Reserve the robots at their homes, all or nothing; -> Reserved."""

    robots: Pairs


@dataclass(frozen=True)
class Assign:
    """Command each robot to do its part of ``task``; -> Acked."""

    members: tuple[Member, ...]
    task: Task


@dataclass(frozen=True)
class Remind:
    """Send these robots their assign again (no answer expected: their states tell)."""

    members: tuple[Member, ...]
    task: Task


@dataclass(frozen=True)
class Confirm:
    """Make the robots' holds at other clouds firm (the request is dispatched)."""

    robots: Pairs


@dataclass(frozen=True)
class Release:
    """Give robots back to their homes."""

    robots: Pairs
    why: str


@dataclass(frozen=True)
class ReleaseAll:
    """Drop every hold this cloud's store has for the request (a selection starts over)."""


@dataclass(frozen=True)
class StopRobots:
    """Tell the robots to stop working on this request (harmless if they are not)."""

    robots: Pairs


@dataclass(frozen=True)
class Unclaim:
    """The robots a selection chose are reserved, or not: their claim ends."""

    robots: Pairs


@dataclass(frozen=True)
class RobotFailed:
    """A robot failed its part (or did not take it): counted, and held against it."""

    robot: str
    cloud: str
    cause: Cause
    why: str


@dataclass(frozen=True)
class RobotDone:
    """A robot finished its part."""

    robot: str


@dataclass(frozen=True)
class Follow:
    """Route these robots' reports to this request (and watch them at other clouds)."""

    robots: Pairs


@dataclass(frozen=True)
class Unfollow:
    robots: Pairs


Effect = (
    Commit
    | Note
    | SaveSelection
    | Publish
    | Select
    | Reserve
    | Assign
    | Remind
    | Confirm
    | Release
    | ReleaseAll
    | StopRobots
    | Unclaim
    | RobotFailed
    | RobotDone
    | Follow
    | Unfollow
)
Step = tuple[Life, list[Effect]]


# -- the function -------------------------------------------------------------------


def decide(life: Life, event: Event, now: Now) -> Step:
    """What the request does on ``event``: its next life, and the effects to carry out."""
    handler: Callable[[Life, Any, Now], Step] = _HANDLERS[type(event)]
    return handler(life, event, now)


def _on_start(life: Life, event: Start, now: Now) -> Step:
    if life.final or life.attempt is not None:
        return life, []  # over, or started already
    if life.state in ("dispatched", "underway"):
        if not life.members:
            return _end(life, "failed", reason="its coalition was lost in a restart of the IaaS")
        grace = now.mono + max(0.0, life.rules.restart_grace - life.rules.offline_after)
        members = {
            r: replace(m, since=grace, heard_at=grace, progressed_at=grace, confirmed=False)
            for r, m in life.members.items()
        }
        life = replace(life, members=members, resumed=True)
        return life, [
            Follow(_pairs(members.values())),
            Note("resumed after a restart of the IaaS; waiting for its robots to report"),
        ]
    effects: list[Effect] = []
    if event.resumed:
        effects += [ReleaseAll(), Note("resumed after a restart of the IaaS")]
    if life.state == "received":
        effects.append(Commit("selecting"))
        life = replace(life, state="selecting")
    life, more = _begin(life, "dispatch", life.task, 1, (), now)
    return life, effects + more


def _on_selected(life: Life, event: Selected, now: Now) -> Step:
    attempt = life.attempt
    if attempt is None or attempt.stage != "selecting" or life.final:
        # An answer to an attempt that is over: what it chose is free again.
        if event.chosen:
            return life, [Unclaim(_pairs(event.chosen))]
        return life, []
    notes: list[Effect] = [Note(n) for n in event.notes]
    if event.chosen is None:
        reason = event.reason or "no feasible coalition"
        if attempt.purpose == "dispatch":
            state = "rejected" if event.complete else "failed"
            life, effects = _end(life, state, reason=reason, selection=dict(event.selection))
            return life, notes + effects
        life, effects = _replacement_failed(life, attempt, reason)
        return life, notes + effects
    chosen = tuple(
        replace(m, since=now.mono, heard_at=now.mono, progressed_at=now.mono, confirmed=False)
        for m in event.chosen
    )
    attempt = replace(attempt, stage="reserving", chosen=chosen, selection=event.selection)
    return replace(life, attempt=attempt), [*notes, Reserve(attempt.pairs)]


def _on_reserved(life: Life, event: Reserved, now: Now) -> Step:
    attempt = life.attempt
    if attempt is None or attempt.stage != "reserving":
        return life, []
    # Reserved or not, the robots' claim ends: the store's reservation (and
    # the route that follows) keep them now, or they are free.
    unclaim = Unclaim(attempt.pairs)
    if life.final:
        # All or nothing: with robots taken, nothing of this try is held.
        if event.taken:
            return replace(life, attempt=None), [unclaim]
        return replace(life, attempt=None), [unclaim, Release(attempt.pairs, "the request is over")]
    if event.taken:
        life = replace(life, excluded=life.excluded | set(event.taken))
        life, more = _retry(
            life,
            attempt,
            f"robots {', '.join(event.taken)} were taken by another request meanwhile",
            now,
        )
        return life, [unclaim, *more]
    attempt = replace(attempt, stage="assigning")
    return replace(life, attempt=attempt), [
        Follow(attempt.pairs),
        unclaim,
        Assign(attempt.chosen, attempt.task),
    ]


def _on_acked(life: Life, event: Acked, now: Now) -> Step:
    attempt = life.attempt
    if attempt is None or attempt.stage != "assigning":
        return life, []
    if life.final:
        # Robots are always told: those that took the task after all stop now.
        return replace(life, attempt=None), [
            StopRobots(attempt.pairs),
            Release(attempt.pairs, "the request is over"),
        ]
    if event.refused:
        # A robot that did not answer may act on the command late: tell it to
        # stop now, and every robot of the try is given back.
        stop: list[Effect] = [
            StopRobots(attempt.pairs),
            Unfollow(attempt.pairs),
            Release(attempt.pairs, "refused"),
        ]
        clouds = dict(attempt.pairs)
        stop += [
            RobotFailed(r, clouds[r], "no_ack", event.refused[r].rstrip("."))
            for r in sorted(event.unanswered)
            if r in event.refused and r in clouds
        ]
        life = replace(life, excluded=life.excluded | set(event.refused))
        why = "; ".join(
            w.rstrip(".")
            if r in event.unanswered
            else f"robot {r} refused the task: {w.rstrip('.')}"
            for r, w in event.refused.items()
        )
        others = [r for r, _ in attempt.pairs if r not in event.refused]
        if others:  # their history would not name them otherwise
            why += f"; {', '.join(others)} told to stop"
        life, more = _retry(life, attempt, why, now)
        return life, stop + more
    if attempt.purpose == "dispatch":
        members = {m.robot: m for m in attempt.chosen}
        selection = {
            **attempt.selection,
            "assignments": [m.to_json() for m in members.values()],
            "dispatched_at": now.wall,
        }
        life = replace(
            life,
            state="dispatched",
            members=members,
            attempt=None,
            selection=selection,
            dispatched_at=now.wall,
        )
        n = len(members)
        effects: list[Effect] = [
            Commit(
                "dispatched",
                detail=f"{n} robot{'s' if n != 1 else ''}: {', '.join(members)}",
                selection=selection,
            ),
            Confirm(attempt.pairs),
        ]
        life, more = _advance(life, quiet=True)
        return life, effects + more
    members = {**life.members, **{m.robot: m for m in attempt.chosen}}
    replacements = [
        *life.selection.get("replacements", []),
        {"failed": list(attempt.replacing), "by": [m.robot for m in attempt.chosen]},
    ]
    selection = {
        **life.selection,
        "assignments": [m.to_json() for m in members.values()],
        "replacements": replacements,
        "current": current_point(members.values()),
    }
    life = replace(life, members=members, attempt=None, selection=selection)
    failed = ", ".join(attempt.replacing)
    effects = [
        SaveSelection(selection),
        Confirm(attempt.pairs),
        Note(f"robot {failed} replaced by {', '.join(m.robot for m in attempt.chosen)}"),
    ]
    if life.failed:  # more robots failed while this one was being replaced
        life, more = _replace_or_finish(life, now)
    else:
        life, more = _advance(life, quiet=True)
    return life, effects + more


def _on_report(life: Life, event: RobotReport, now: Now) -> Step:
    if life.final:
        return life, []
    attempt = life.attempt
    member = life.members.get(event.robot)
    if member is None:
        if attempt is not None and any(m.robot == event.robot for m in attempt.chosen):
            chosen = tuple(
                _heard(m, event, now) if m.robot == event.robot else m for m in attempt.chosen
            )
            return replace(life, attempt=replace(attempt, chosen=chosen)), []
        return life, []
    if member.phase == "done":
        return life, []
    if event.phase is not None:
        if event.phase == "failed" or (event.status == "offline" and event.phase != "done"):
            return _member_failed(life, event.robot, *_why_failed(event), now)
        heard = _heard(member, event, now)
        life, effects = _advance(_with(life, heard))
        if heard.phase == "done":
            effects = [RobotDone(event.robot), *effects]
        elif now.mono - member.heard_at > life.rules.remind_after:
            # Back from a silence on this request's task: tell it again that
            # the task is still its (a restarted gateway keeps the order).
            effects = [Remind((heard,), life.task), *effects]
        return life, effects
    if event.last_phase == "done":
        done = replace(member, phase="done", progress=1.0, heard_at=now.mono, confirmed=True)
        life, effects = _advance(_with(life, done))
        return life, [RobotDone(event.robot), *effects]
    if event.last_phase == "failed" or event.status == "offline":
        return _member_failed(life, event.robot, *_why_failed(event), now)
    if member.confirmed:
        return _member_failed(
            life, event.robot, "dropped", "it no longer reports this request", now
        )
    if now.mono - member.since > life.rules.offline_after:
        why = "it does not report this request"
        if life.resumed:
            why = "it no longer reports this request after the restart"
        return _member_failed(life, event.robot, "dropped", why, now)
    return _with(life, replace(member, heard_at=now.mono)), []


def _on_tick(life: Life, event: Tick, now: Now) -> Step:
    if life.final:
        return life, []
    effects: list[Effect] = []
    for member in list(life.members.values()):
        if member.phase == "done":
            continue
        failure = _watchdog(life, member, now)
        if failure is not None:
            life, more = _member_failed(life, member.robot, *failure, now)
            effects += more
            if life.final:
                return life, effects
    rules, task = life.rules, life.task
    if (
        life.state in ("dispatched", "underway")
        and life.dispatched_at is not None
        and now.wall > rules.due(life.dispatched_at, task.max_time)
    ):
        working = [m.robot for m in life.followed() if m.phase != "done"]
        life, more = _end(
            life,
            "failed",
            reason=f"it ran past its max_time of {task.max_time:g} s (robot time) plus the "
            f"tolerance of {rules.tolerance(task.max_time):g} s; "
            + (f"{', '.join(working)} told to stop" if working else "no robot was left working"),
        )
        effects += more
    return life, effects


def _watchdog(life: Life, member: Member, now: Now) -> tuple[Cause, str] | None:
    """Whether a robot of the coalition has failed by the clock: silent, overrun, stalled."""
    rules = life.rules
    started = None
    if life.dispatched_at is not None:
        started = life.dispatched_at + member.offset / rules.time_scale
    moving = member.confirmed and member.phase in ("travel", "work")
    return rules.failure(
        now.mono - member.heard_at,
        started,
        member.time,
        now.wall,
        now.mono - member.progressed_at if moving else None,
    )


def _on_cancel(life: Life, event: CancelAsked, now: Now) -> Step:
    if life.final:
        return life, []
    return _end(life, "canceled", detail="canceled by the application")


def _on_loan_ended(life: Life, event: LoanEnded, now: Now) -> Step:
    if life.final:
        return life, []
    note: list[Effect] = [Note(loan_ended_note(event.robot, event.home, event.why))]
    if event.robot not in life.members:
        return life, note
    life, effects = _member_failed(
        life, event.robot, "loan_ended", f"its home {event.home} ended the loan", now
    )
    return life, note + effects


def _on_crashed(life: Life, event: Crashed, now: Now) -> Step:
    if life.final:
        return life, []
    return _end(life, "failed", reason=f"internal error: {event.reason}")


_HANDLERS: dict[type, Callable[[Life, Any, Now], Step]] = {
    Start: _on_start,
    Selected: _on_selected,
    Reserved: _on_reserved,
    Acked: _on_acked,
    RobotReport: _on_report,
    Tick: _on_tick,
    CancelAsked: _on_cancel,
    LoanEnded: _on_loan_ended,
    Crashed: _on_crashed,
}


# -- the steps the handlers share -----------------------------------------------------


def _why_failed(event: RobotReport) -> tuple[Cause, str]:
    """Why a robot that reports its task failed, or that went offline at it, failed it."""
    # The robot's own sentence, on one line (a history line, a log line).
    said = f": {' '.join(event.reason.split()).rstrip('.')}" if event.reason else ""
    if event.battery <= 0:
        return "offline", f"its battery died{said}"
    if event.status == "offline":
        return "offline", f"it went offline{said}"
    # A fleet gateway reports a task its vehicle dropped while still online.
    return "reported", f"it reported that it cannot finish its task{said}"


def _begin(
    life: Life, purpose: Purpose, task: Task, number: int, replacing: tuple[str, ...], now: Now
) -> Step:
    """Start an attempt: select among every robot in view but the excluded and our own."""
    offset = 0.0
    if purpose == "replace" and life.dispatched_at is not None:
        offset = max(0.0, (now.wall - life.dispatched_at) * life.rules.time_scale)
    attempt = Attempt(purpose, number, task, replacing=replacing)
    exclude = life.excluded | set(life.members) | set(replacing)
    return replace(life, attempt=attempt), [Select(task, frozenset(exclude), offset, number)]


def _retry(life: Life, attempt: Attempt, why: str, now: Now) -> Step:
    if attempt.number >= life.rules.attempts:
        reason = (
            f"no coalition could be reserved and dispatched in {life.rules.attempts} "
            f"attempts; robots kept being taken or refusing (last: {why})"
        )
        if attempt.purpose == "dispatch":
            return _end(life, "failed", reason=reason)
        return _replacement_failed(life, attempt, reason)
    life, effects = _begin(
        life, attempt.purpose, attempt.task, attempt.number + 1, attempt.replacing, now
    )
    return life, [Note(f"{why}; selecting again (attempt {attempt.number + 1})"), *effects]


def _member_failed(life: Life, robot: str, cause: Cause, why: str, now: Now) -> Step:
    member = life.members[robot]
    members = {r: m for r, m in life.members.items() if r != robot}
    life = replace(
        life, members=members, excluded=life.excluded | {robot}, failed=(*life.failed, robot)
    )
    effects: list[Effect] = [
        Unfollow((member.pair,)),
        StopRobots((member.pair,)),
        Release((member.pair,), f"robot failed: {why}"),
        Note(f"robot {robot} failed: {why}"),
        RobotFailed(robot, member.cloud, cause, why),
    ]
    if life.attempt is not None:
        return life, effects  # the replacement under way looks again when it ends
    life, more = _replace_or_finish(life, now)
    return life, effects + more


def _replace_or_finish(life: Life, now: Now) -> Step:
    """After failures: select robots for what is missing, or go on without them."""
    missing = missing_capabilities(life.task, life.members.values())
    failed, life = life.failed, replace(life, failed=())
    if not missing:
        return _advance(life)
    task = life.task
    elapsed = 0.0
    if life.dispatched_at is not None:
        elapsed = max(0.0, (now.wall - life.dispatched_at) * life.rules.time_scale)
    time_left = task.max_time - elapsed
    cost_left = task.max_cost - sum(m.cost for m in life.members.values())
    robots_left = task.max_robots - len(life.members)
    if time_left <= 0:
        reason = f"no time is left of max_time {task.max_time:g} s"
    elif cost_left < 0 or robots_left < 1:
        reason = "no cost or robot is left within the request's limits"
    else:
        sub = task.model_copy(
            update={
                "sensing": {k: v for k, v in missing.items() if k in task.sensing},
                "actuating": {k: v for k, v in missing.items() if k in task.actuating},
                "max_robots": robots_left,
                "max_cost": cost_left,
                "max_time": time_left,
            }
        )
        return _begin(life, "replace", sub, 1, failed, now)
    return _end(
        life,
        "failed",
        reason=f"robot {', '.join(failed)} failed and no replacement was found: {reason}",
    )


def _replacement_failed(life: Life, attempt: Attempt, reason: str) -> Step:
    failed = ", ".join(attempt.replacing)
    return _end(
        replace(life, attempt=None),
        "failed",
        reason=f"robot {failed} failed and no replacement was found: {reason}",
    )


def _advance(life: Life, quiet: bool = False) -> Step:
    """Move a dispatched request on as its robots' phases say; else publish the progress."""
    phases = [m.phase for m in life.members.values()]
    effects: list[Effect] = []
    complete = (
        bool(phases)
        and all(p == "done" for p in phases)
        and life.attempt is None
        and not missing_capabilities(life.task, life.members.values())
    )
    moving = any(p in ("travel", "work", "done") for p in phases)
    if life.state == "dispatched" and (moving or complete):
        detail = None if complete else "the robots are moving"
        effects.append(Commit("underway", detail=detail))
        life = replace(life, state="underway")
    if complete:
        life, more = _end(life, "completed", detail="every robot finished its part")
        return life, effects + more
    if not effects and not quiet:
        effects.append(Publish())
    return life, effects


def _end(
    life: Life,
    state: str,
    reason: str | None = None,
    detail: str | None = None,
    selection: Mapping[str, Any] | None = None,
) -> Step:
    """Commit a final state, then stop and give back every robot the request still has."""
    robots = life.followed()
    effects: list[Effect] = [Commit(state, reason, detail, selection)]
    if state != "completed":
        working = tuple(m.pair for m in robots if m.phase != "done")
        if working:
            effects.append(StopRobots(working))
    pairs = _pairs(robots)
    if pairs:
        effects += [Release(pairs, f"the request is {state}"), Unfollow(pairs)]
    attempt = life.attempt
    if attempt is not None and attempt.stage == "selecting":
        attempt = None  # nothing was reserved yet; a late Selected is ignored
    return replace(life, state=state, attempt=attempt, failed=()), effects


# -- small pure helpers ------------------------------------------------------------------


_PHASE_ORDER = {"pending": 0, "travel": 1, "work": 2, "done": 3}


def _heard(member: Member, event: RobotReport, now: Now) -> Member:
    if event.phase is None:
        return replace(member, heard_at=now.mono)
    # Progress never goes back: an older report (reordered, replayed) moves
    # nothing, and does not count as progress for the watchdog.
    ahead = _PHASE_ORDER.get(event.phase, 0) - _PHASE_ORDER.get(member.phase, 0)
    moved = ahead > 0 or (ahead == 0 and event.progress > member.progress)
    return replace(
        member,
        phase=event.phase if ahead > 0 else member.phase,
        progress=max(event.progress, member.progress),
        heard_at=now.mono,
        confirmed=True,
        progressed_at=now.mono if moved else member.progressed_at,
    )


def _with(life: Life, member: Member) -> Life:
    return replace(life, members={**life.members, member.robot: member})


def _pairs(members: Iterable[Member]) -> Pairs:
    return tuple(m.pair for m in members)


def loan_ended_note(robot: str, home: str, why: str) -> str:
    return f"{home} ended the loan of robot {robot}: {why}"


def missing_capabilities(task: Task, members: Iterable[Member]) -> dict[str, int]:
    """Capability -> how many more robots must bring it than ``members`` do."""
    members = list(members)
    missing = {}
    for name, need in task.required.items():
        have = sum(name in m.capabilities for m in members)
        if have < need:
            missing[name] = need - have
    return missing


def current_point(members: Iterable[Member]) -> dict[str, Any]:
    """The coalition as it is now, as a point like the front's (T counted from dispatch).

    T is the latest finish, each robot's ``offset`` (when it was sent, after
    the request's dispatch) plus its t_i; C is the sum of the c_i of the
    robots in the coalition now.
    """
    members = list(members)
    return {
        "robots": sorted(m.robot for m in members),
        "time": max((m.offset + m.time for m in members), default=0.0),
        "cost": sum(m.cost for m in members),
        "size": len(members),
    }


def life_of(
    request_id: str,
    task: Task,
    state: str,
    selection: Mapping[str, Any] | None,
    rules: Rules,
) -> Life:
    """The life of a stored request, as a restart finds it."""
    selection = dict(selection or {})
    members = {m.robot: m for m in (Member.from_json(a) for a in selection.get("assignments", []))}
    dispatched_at = selection.get("dispatched_at")
    return Life(
        request_id=request_id,
        task=task,
        rules=rules,
        state=state,
        members=members if state in ("dispatched", "underway") else {},
        selection=selection,
        dispatched_at=float(dispatched_at) if dispatched_at is not None else None,
    )
