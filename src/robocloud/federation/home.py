"""What this cloud answers to the other clouds about its own robots (its ``HomeDesk``).

A robot is reserved only at its home: for a request of another cloud (the
origin) the home lends it, a row of the store's loans table, so the store's
one guarantee (one robot, one holder) covers this cloud's requests and its
loans together. The home alone talks to its robots: it forwards a dispatch
only for a robot lent to the sender's request.

The sender of a command is the cloud named by the key it came on (with
mutual TLS, the router let only that cloud's certificate send on it), never
what the payload says. The home enforces the leases:

- a loan starts as a lease the home sets, at most ``lease_max`` seconds
  whatever the origin asks, and stays a lease until the home forwarded the
  robot's dispatch (and the robot accepted it); then the origin's confirm
  makes it firm (it no longer lapses). A confirm without a live lease of the
  sender's request, or before that dispatch, is refused;
- a loan ends when its robot reports the task done or failed, when the
  origin releases or cancels it, when its lease lapses, when the origin says
  its request is over or no longer uses the robot (``reconcile``, every few
  seconds), or when the origin stays unreachable ``origin_deadline`` seconds
  after the robot is idle or done. Then the origin is told once it is back
  (it asks each home it borrowed from: ``OriginStatus.loan_ended``), and the
  home logs it at both moments.

Commands that touch another origin's loan are refused and logged as warnings.

Why one long file: every answer of a home to another cloud (questions,
reservations, confirms, releases, dispatches, cancels) checks the same
loans in memory under one lock; the reconciliation is in ``reconcile.py``
and the lease bounds in ``lending.py``.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable, Collection, Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from datetime import datetime, timedelta

from robocloud.domain import Robot, is_final
from robocloud.domain.mission_ids import holder_of
from robocloud.errors import RoboCloudError
from robocloud.federation.capabilities import Announced
from robocloud.federation.lending import (
    LEND_MIN_BATTERY,
    LEND_SHARE,
    RESERVE_BURST,
    RESERVE_RATE,
    Aside,
    ReserveRate,
    Undispatched,
    never_aside,
    over_share,
    set_aside,
    unfit,
)
from robocloud.federation.messages import (
    MAX_ITEMS,
    CloudInfo,
    Dispatch,
    Done,
    FleetReply,
    IdleQuery,
    LoanNotice,
    LoanQuery,
    LoanReply,
    Release,
    RequestStatus,
    Reservation,
    ReserveReply,
    StatusQuery,
    StatusReply,
)
from robocloud.fleet.link import RobotLink
from robocloud.fleet.messages import Ack, Assign, State
from robocloud.storage import Loan, RequestStore
from robocloud.storage.rules import utc_now

log = logging.getLogger(__name__)

LEASE_MAX = 30.0  # seconds: the longest lease this home grants
ORIGIN_DEADLINE = 60.0  # seconds an origin may stay away once its robot is idle or done


@dataclass(frozen=True)
class _Lent:
    """What ``lent_for`` needs of a robot's latest loan, kept in memory.

    An ended loan stays (``active`` false) until the robot's next loan: a
    stale copy of it, read before it ended, must not bring it back.
    """

    origin: str
    request_id: str
    expires_at: datetime | None
    version: datetime  # the loan's updated_at: an older write never replaces a newer one
    active: bool = True
    firm: bool = False


def _stray_commands(reservation: Reservation) -> str | None:
    """Why a reservation's commands do not fit it (each for one of its robots, for its request)."""
    robots = set(reservation.robots)
    for dispatch in reservation.dispatch:
        if (
            dispatch.robot not in robots
            or holder_of(dispatch.command.request_id) != reservation.request_id
        ):
            return (
                f"the command for {dispatch.robot} is not for a robot and request of "
                "this reservation."
            )
    if len({d.robot for d in reservation.dispatch}) != len(reservation.dispatch):
        return "a reservation carries at most one command per robot."
    return None


def working_for(state: State | None, request_id: str) -> bool:
    """Whether the robot reports working on the request (a task of it, for a mission), online."""
    return (
        state is not None
        and state.status != "offline"
        and state.task is not None
        and holder_of(state.task.request_id) == request_id
        and state.task.phase in ("travel", "waiting", "work")
    )


class Home:
    def __init__(
        self,
        cloud: str,
        store: RequestStore,
        link: RobotLink,
        trusted: Iterable[str] | None = None,
        api: str | None = None,
        *,
        lease_max: float = LEASE_MAX,
        origin_deadline: float = ORIGIN_DEADLINE,
        lend_share: float = LEND_SHARE,
        reserve_rate: float = RESERVE_RATE,
        set_aside: Callable[[str], Aside | None] = never_aside,
        coalition_of: Callable[[str], list[str]] = lambda request_id: [],
        missions: Callable[[str], tuple[bool, bool] | None] = lambda request_id: None,
        kept: Callable[[], Collection[str]] = frozenset,
        monotonic: Callable[[], float] = time.monotonic,
        clock: Callable[[], datetime] = utc_now,
    ) -> None:
        self.cloud = cloud
        self.store = store
        self.link = link
        self.trusted = set(trusted) if trusted else None  # None: every cloud
        self.api = api
        # The capability names this cloud's robots have announced (its CloudInfo says them).
        self.announced = Announced()
        self.lease_max = lease_max
        self.origin_deadline = origin_deadline
        self.lend_share = lend_share
        self.reserve_rate = ReserveRate(monotonic, reserve_rate, RESERVE_BURST)
        self._undispatched = Undispatched(cloud, lease_max, monotonic)
        # The robots this cloud's own selections leave out for failing (the
        # IaaS's RobotRoutes.aside): neither offered nor lent to other clouds.
        self.set_aside = set_aside
        # The robots working for one of this cloud's requests now (the IaaS's
        # RobotRoutes): what another cloud that lent some is told.
        self.coalition_of = coalition_of
        # This cloud's missions (kept in memory, not in the store): for a
        # mission id, (known, final), else None; and the robots they hold now,
        # which this home neither offers nor lends.
        self.missions = missions
        self.kept = kept
        self._clock = clock
        self._lock = threading.Lock()
        self._lent: dict[str, _Lent] = {}
        self._bound_refusals: dict[str, int] = {}  # origin -> reserves refused by a bound
        self._dispatched: set[tuple[str, str]] = set()  # (robot, request): accepted its dispatch
        self._robot_json: dict[str, tuple[Robot, bytes]] = {}  # id -> (the Robot, its JSON)
        # Commands that came with a reservation, sent to their robots at once.
        self._dispatcher = ThreadPoolExecutor(8, thread_name_prefix=f"home-{cloud}")
        self._cloud_json = json.dumps(cloud).encode()
        for loan in store.loans():
            self._remember(loan)
        link.on_state(self._on_state)

    # -- what the service asks ---------------------------------------------------

    def lent_for(self, robot_id: str) -> str | None:
        """The origin request the robot is lent for now, or None (from memory: cheap)."""
        with self._lock:
            lent = self._lent.get(robot_id)
        if lent is None or not lent.active:
            return None
        if lent.expires_at is not None and lent.expires_at < self._clock():
            return None
        return lent.request_id

    # -- questions (anyone may ask) ---------------------------------------------

    def info(self) -> CloudInfo:
        robots = self.link.robots()
        held = self._held()
        idle = sum(r.status == "idle" and r.id not in held for r in robots)
        offline = sum(r.status == "offline" for r in robots)
        self.announced.learn_robots(robots)
        return CloudInfo(
            cloud=self.cloud,
            robots=len(robots),
            idle=idle,
            offline=offline,
            api=self.api,
            capabilities=self.announced.names(),
        )

    def idle_robots(self, query: IdleQuery) -> bytes:
        """The ``IdleReply``'s JSON: the idle robots, not held nor set aside, that pass
        the query's filter.

        Asked for every selection of every other cloud, with hundreds of
        robots in each reply: each robot's JSON is written once and kept
        while the link gives the same ``Robot`` (it makes a new one only when
        a state changes what the robot says), so a reply is mostly a join.
        """
        # The scatter-gather reaches this cloud's own desk too: its robots are
        # already in the view, so they need not travel.
        if query.origin == self.cloud or not self.trusts(query.origin):
            return self._idle_reply([])
        held = self._held()
        wanted = set(query.capabilities)
        everyone = self.link.robots()
        aside = self.set_aside
        robots = [
            r
            for r in everyone
            if r.status == "idle"
            and r.id not in held
            and r.battery >= query.min_battery
            and (not wanted or not wanted.isdisjoint(r.capabilities))
            and aside(r.id) is None
        ]
        if len(self._robot_json) > len(everyone) + 1000:  # forgotten robots' JSON goes
            self._robot_json = {}
        return self._idle_reply(robots[:MAX_ITEMS])

    def _idle_reply(self, robots: list[Robot]) -> bytes:
        cache = self._robot_json
        parts = []
        for robot in robots:
            kept = cache.get(robot.id)
            if kept is None or kept[0] is not robot:
                kept = cache[robot.id] = (robot, robot.model_dump_json().encode())
            parts.append(kept[1])
        return b'{"cloud":%s,"robots":[%s]}' % (self._cloud_json, b",".join(parts))

    def fleet(self) -> FleetReply:
        held = self._held()
        states = self.link.states()
        out = []
        for robot in self.link.robots()[:MAX_ITEMS]:
            state = states.get(robot.id)
            status = "reserved" if robot.status == "idle" and robot.id in held else robot.status
            out.append(
                {
                    **robot.model_dump(mode="json"),
                    "status": status,
                    "kind": state.kind if state else None,
                    "request": None,
                    "progress": state.task.model_dump(mode="json")
                    if state and state.task
                    else None,
                }
            )
        return FleetReply(cloud=self.cloud, robots=out)

    def status(self, query: StatusQuery) -> StatusReply:
        """This cloud as the origin: what it says of its requests to a home."""
        out = []
        for request_id in query.request_ids:
            mission = self.missions(request_id)
            if mission is not None:
                known, final = mission
                robots = self.coalition_of(request_id) if known and not final else []
                out.append(
                    RequestStatus(request_id=request_id, known=known, final=final, robots=robots)
                )
                continue
            record = self.store.get(request_id)
            if record is None:
                out.append(RequestStatus(request_id=request_id, known=False))
                continue
            robots = self.coalition_of(request_id)
            out.append(
                RequestStatus(
                    request_id=request_id, known=True, final=is_final(record.state), robots=robots
                )
            )
        return StatusReply(requests=out)

    # -- commands (origin: the sender named by the key) -----------------------------

    def reserve(self, origin: str, reservation: Reservation) -> ReserveReply:
        """Lend the robots, all or none; then forward the reservation's commands, if any.

        The commands (``dispatch``) go to the robots only once every robot is
        lent, each as ``dispatch`` would send it; the reply carries their acks.
        """
        refusal = self._check(origin, "reserve", reservation.robots)
        if refusal is None:
            refusal = _stray_commands(reservation)
        if refusal is None:
            refusal, lease = self._bounds(origin, reservation)
        if refusal:
            return ReserveReply(taken=list(reservation.robots), error=refusal)
        kept = self.kept()
        taken = [r for r in reservation.robots if r in kept]  # held by a mission of ours
        if taken:
            return ReserveReply(taken=taken)
        taken = self.store.lend(origin, reservation.request_id, reservation.robots, lease)
        if taken:
            return ReserveReply(taken=taken)
        kept = self.kept()
        taken = [r for r in reservation.robots if r in kept]
        if taken:
            # A mission of ours took one between the check and the loan: it
            # reads the store after taking, so one of the two always sees the other.
            why = "a mission of this cloud took it meanwhile"
            self.store.end_loans(origin, reservation.request_id, reservation.robots, why)
            return ReserveReply(taken=taken)
        self._undispatched.record(origin, reservation.robots, lease)
        self._lent_now(origin, reservation.request_id, reservation.robots, lease)
        commands = reservation.dispatch
        if len(commands) > 1:  # the robots answer at once, not one after the other
            acks = list(self._dispatcher.map(lambda d: self.dispatch(origin, d), commands))
        else:
            acks = [self.dispatch(origin, d) for d in commands]
        return ReserveReply(acks=acks)

    def confirm(self, origin: str, reservation: Reservation) -> ReserveReply:
        refusal = self._check(origin, "confirm", reservation.robots)
        if refusal:
            return ReserveReply(taken=list(reservation.robots), error=refusal)
        request_id, robots = reservation.request_id, reservation.robots
        if all(self._firm(robot, origin, request_id) for robot in robots):
            return ReserveReply()  # confirmed already: nothing to write
        lost = [
            r for r in robots if self._holder(r) != (origin, request_id) or not self.lent_for(r)
        ]
        if not lost:
            states = self.link.states()
            waiting = [
                r
                for r in robots
                if (r, request_id) not in self._dispatched
                and not self._firm(r, origin, request_id)
                and not working_for(states.get(r), request_id)  # (dispatched before a restart)
            ]
            if waiting:
                error = (
                    f"{self.cloud} forwarded no dispatch of {', '.join(waiting)} for request "
                    f"{request_id}: a lease turns firm only once its robot was dispatched."
                )
                self._refuse(origin, "confirm", request_id, waiting, error)
                return ReserveReply(taken=waiting, error=error)
            lost = self.store.confirm_loans(origin, request_id, robots)
        if lost:
            error = (
                f"{self.cloud} has no live lease on {', '.join(lost)} for request {request_id} "
                f"of {origin}: reserve them first (a lease lapses after at most "
                f"{self.lease_max:g} s until the dispatch)."
            )
            self._refuse(origin, "confirm", request_id, lost, error)
            return ReserveReply(taken=lost, error=error)
        self._lent_now(origin, request_id, robots, None)
        return ReserveReply()

    def release(self, origin: str, release: Release) -> Done:
        refusal = self._check(origin, "release", release.robots or [])
        if refusal:
            return Done(ok=False, error=refusal)
        why = release.why or f"released by {origin}"
        ended = self.store.end_loans(origin, release.request_id, release.robots, why)
        self.forget(ended)
        if not ended:
            return self._nothing_lent(origin, "release", release)
        return Done()

    def dispatch(self, origin: str, dispatch: Dispatch) -> Ack:
        command = dispatch.command
        robot, request_id = dispatch.robot, command.request_id
        refusal = self._check(origin, "dispatch", [robot])
        if refusal:
            return Ack.refuse(robot, request_id, refusal)
        holder = self._holder(robot)
        # A mission's robot is lent to the mission and commanded for its tasks.
        lent_to = holder_of(request_id)
        if holder != (origin, lent_to) or self.lent_for(robot) is None:
            error = f"robot {robot} is not lent to request {lent_to} of {origin}."
            self._refuse(origin, "dispatch", request_id, [robot], error)
            return Ack.refuse(robot, request_id, error)
        if not isinstance(command, Assign):
            return self.link.start(robot, request_id)
        ack = self.link.assign(robot, command)
        if ack.ok:
            self._undispatched.dispatched(origin, robot)
            # Now the origin may confirm the lease (firm). Kept in memory, not
            # written: the origin confirms at once, and the robot's own state
            # tells the same after a restart of this IaaS.
            with self._lock:
                self._dispatched.add((robot, lent_to))
        return ack

    def cancel(self, origin: str, release: Release) -> Done:
        refusal = self._check(origin, "cancel", release.robots or [])
        if refusal:
            return Done(ok=False, error=refusal)
        request_id = release.request_id
        lent = self.store.loans(origin, request_id)
        robots = [
            loan.robot for loan in lent if release.robots is None or loan.robot in release.robots
        ]
        if not robots:
            self._stop_strays(request_id, release.robots or [])
            return self._nothing_lent(origin, "cancel", release)
        for robot in robots:
            self.stop(robot, request_id)
        why = release.why or f"canceled by {origin}"
        self.forget(self.store.end_loans(origin, request_id, robots, why))
        return Done()

    def loans(self, origin: str, query: LoanQuery) -> LoanReply:
        """What the origin asks once it is back: the loans this home ended without it."""
        if not self.trusts(origin):
            return LoanReply(cloud=self.cloud)
        for loan in self.store.told(origin, query.told):
            log.info(
                "%s, back, took in that the loan of %s to request %s ended: %s",
                origin,
                loan.robot,
                loan.request_id,
                loan.reason,
            )
        ended = [
            LoanNotice(
                loan=loan.id,
                robot=loan.robot,
                request_id=loan.request_id,
                why=(loan.reason or "ended by the home")[:500],
            )
            for loan in self.store.untold_loans(origin)[:MAX_ITEMS]
        ]
        return LoanReply(cloud=self.cloud, held=self.store.count_loans(origin), ended=ended)

    def stop(self, robot: str, request_id: str) -> None:
        """Tell a robot to stop working for ``request_id``: for a mission, the task it is on."""
        state = self.link.state(robot)
        task = state.task if state is not None else None
        on = task.request_id if task is not None else request_id
        self.link.cancel(robot, on if holder_of(on) == request_id else request_id)

    def _held(self) -> set[str]:
        """The robots this cloud holds: reserved or lent in its store, or kept by its missions."""
        held = set(self.store.reservations())
        held.update(self.kept())
        return held

    # -- checks ------------------------------------------------------------------------

    def _bounds(self, origin: str, reservation: Reservation) -> tuple[str | None, float]:
        """(why the reservation exceeds a lending bound, or None; the lease to grant).

        The bounds of ``robocloud.federation.lending``: the rate, the robots'
        fitness (a robot set aside here is not lent), the origin's share, and
        ``lease_max`` from the first reservation (``Undispatched``: renewals,
        other request ids and releases in between included).
        """
        request_id, robots = reservation.request_id, reservation.robots
        refusal = self.reserve_rate.take(origin)
        asked = min(reservation.lease_seconds or self.lease_max, self.lease_max)
        lease = asked
        if refusal is None:
            # Counted, and this request's read, by the store's indexes: reading every loan
            # of the origin at each reservation made a thousand loans quadratic.
            held = self.store.count_loans(origin)
            mine = {loan.robot for loan in self.store.loans(origin, request_id)}
            # Robots another holds are left to the store, which answers them taken.
            new = [r for r in robots if r not in mine and self._holder(r) is None]
            fleet = self.link.robots()
            refusal = (
                unfit(new, {r.id: r for r in fleet}, LEND_MIN_BATTERY)
                or set_aside(new, self.set_aside, self.cloud)
                or over_share(origin, held, len(new), len(fleet), self.lend_share, self.cloud)
            )
            if refusal is None:
                ours = [r for r in robots if r in mine or r in new]
                lease, refusal = self._undispatched.grant(origin, ours, asked)
        if refusal is not None:
            self._refused_bound(origin, request_id, refusal)
        return refusal, lease

    def bound_refusals(self) -> dict[str, int]:
        """Reservations refused by a lending bound, by origin (a copy: the metric)."""
        with self._lock:
            return dict(self._bound_refusals)

    def _refused_bound(self, origin: str, request_id: str, refusal: str) -> None:
        """Log a reservation refused by a bound: the first of each origin, then every 100th."""
        with self._lock:
            count = self._bound_refusals[origin] = self._bound_refusals.get(origin, 0) + 1
        if count == 1 or count % 100 == 0:
            log.warning(
                "refused a reserve from %s for request %s (%d so far): %s",
                origin,
                request_id,
                count,
                refusal,
            )

    def trusts(self, origin: str) -> bool:
        """Whether this home lends to, and borrows from, ``origin`` (itself included)."""
        return self.trusted is None or origin in self.trusted or origin == self.cloud

    def _check(self, origin: str, what: str, robots: Iterable[str]) -> str | None:
        if not origin:
            return "a command must come on a key that names its sender."
        if not self.trusts(origin):
            error = f"{self.cloud} does not trust {origin}."
            log.warning("refused a %s from %s: %s", what, origin, error)
            return error
        known = self.link.states()  # a copy of a dict: cheaper than the robots() list
        unknown = [r for r in robots if r not in known]
        if unknown:
            return f"{self.cloud} has no robot {', '.join(unknown[:10])}."
        return None

    def _refuse(
        self, origin: str, what: str, request_id: str, robots: Iterable[str], error: str
    ) -> None:
        """Log a refused command: a warning when it touched another origin's loan."""
        others = {
            robot: holder
            for robot in robots
            if (holder := self._holder(robot)) is not None and holder[0] != origin
        }
        if others:
            log.warning(
                "refused a %s from %s for request %s: %s is lent to %s",
                what,
                origin,
                request_id,
                ", ".join(others),
                ", ".join(sorted({f"{o}'s request {r}" for o, r in others.values()})),
            )
        else:
            log.info("refused a %s from %s: %s", what, origin, error)

    def _stop_strays(self, request_id: str, robots: Iterable[str]) -> None:
        """Stop robots that still work for a request although no loan holds them any more.

        A loan the home ended while its robot could not hear the cancel (it was
        silent) leaves the robot working; the origin's cancel stops it then.
        Only a robot no loan holds, and only from that request.
        """
        states = self.link.states()
        for robot in robots:
            if self._holder(robot) is None and working_for(states.get(robot), request_id):
                log.info("stopping %s, which still works for request %s", robot, request_id)
                self.stop(robot, request_id)

    def _nothing_lent(self, origin: str, what: str, release: Release) -> Done:
        """A release or cancel that ended nothing: harmless, unless it aimed at another's loans."""
        aimed = [
            loan
            for loan in self.store.loans(request_id=release.request_id)
            if loan.origin != origin and (release.robots is None or loan.robot in release.robots)
        ]
        aimed += [
            loan
            for robot in release.robots or []
            if (loan := self.store.loan_of(robot)) is not None
            and loan.origin != origin
            and loan not in aimed
        ]
        if not aimed:
            return Done()  # already released: repeating it is harmless
        robots = ", ".join(sorted({loan.robot for loan in aimed}))
        log.warning(
            "refused a %s from %s for request %s: %s is lent to %s",
            what,
            origin,
            release.request_id,
            robots,
            ", ".join(sorted({loan.origin for loan in aimed})),
        )
        return Done(
            ok=False,
            error=f"{origin} holds no loan of {robots} for request {release.request_id}.",
        )

    # -- the loans in memory (lent_for) ---------------------------------------------

    def _holder(self, robot: str) -> tuple[str, str] | None:
        with self._lock:
            lent = self._lent.get(robot)
        return None if lent is None or not lent.active else (lent.origin, lent.request_id)

    def _firm(self, robot: str, origin: str, request_id: str) -> bool:
        """Whether the robot is firmly lent to this origin request (from memory)."""
        with self._lock:
            lent = self._lent.get(robot)
        return (
            lent is not None
            and lent.active
            and lent.firm
            and (lent.origin, lent.request_id) == (origin, request_id)
        )

    def _remember(self, loan: Loan) -> None:
        with self._lock:
            known = self._lent.get(loan.robot)
            if known is not None and known.version > loan.updated_at:
                return
            self._lent[loan.robot] = _Lent(
                loan.origin,
                loan.request_id,
                loan.expires_at,
                loan.updated_at,
                loan.active,
                loan.state == "firm",
            )

    def _lent_now(
        self, origin: str, request_id: str, robots: Iterable[str], lease: float | None
    ) -> None:
        """What the store just committed (a lease, or firm with None), without reading it back.

        Stamped with this moment, later than the store's own: a copy of the
        loan read before the write cannot replace it. A lease's end is
        reckoned from now too, a little later than the store's: ``lent_for``
        may say lent a few milliseconds past the lapse, never the reverse
        for a loan the store still holds.
        """
        now = self._clock()
        with self._lock:
            for robot in robots:
                known = self._lent.get(robot)
                expires_at = None if lease is None else now + timedelta(seconds=lease)
                if (
                    lease is not None
                    and known is not None
                    and known.active
                    and (known.origin, known.request_id) == (origin, request_id)
                ):
                    if known.firm:
                        continue  # a firm loan stays firm
                    if known.expires_at is not None and expires_at is not None:
                        expires_at = max(expires_at, known.expires_at)
                self._lent[robot] = _Lent(origin, request_id, expires_at, now, True, lease is None)

    def forget(self, ended: Iterable[Loan]) -> None:
        """Loans the store just ended: this home's memory of them follows."""
        for loan in ended:
            self._remember(loan)
            with self._lock:
                self._dispatched.discard((loan.robot, loan.request_id))

    def _on_state(self, state: State) -> None:
        """A lent robot finished its task: the loan ends and the robot is this cloud's again."""
        task = state.task
        if task is None or task.phase not in ("done", "failed"):
            return
        holder = self._holder(state.id)
        if holder is None or holder[1] != task.request_id:
            return
        why = "its task is done" if task.phase == "done" else f"robot {state.id} failed"
        try:
            self.forget(self.store.end_loans(holder[0], task.request_id, [state.id], why))
        except RoboCloudError:
            log.exception("could not end the loan of %s", state.id)
