"""The federation view: every robot a request may use, and how to reach it.

The thesis's Virtualization Engine asks the Task Delegator Engine for the idle
robots of all IaaSs. Here that is this cloud's robots (from its robot link,
minus those its store holds) plus a scatter-gather query that every other
live cloud answers within a timeout. Reservations, commands and cancels go to
each robot's home: this cloud's store and link for its own robots, the
overlay for the others.

Without an overlay (``overlay=None``) the view is this cloud alone.

The view remembers the homes it borrowed robots from (``lenders``): once
this cloud is back after being away, it asks them which of its loans they
ended meanwhile (``robocloud.federation.home.Home.reconcile``).

Why one long file: the one place a request reaches robots, its own cloud's
and the others' alike (gathering, reservations, commands, what it keeps of
the other clouds' answers).
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field

from robocloud.domain import Robot, RobotLike, Task
from robocloud.errors import RoboCloudError
from robocloud.federation.messages import Dispatch, IdleQuery, Release, Reservation
from robocloud.federation.overlay import Gathered, Overlay
from robocloud.fleet.link import RobotLink, StateListener
from robocloud.fleet.messages import Ack, Assign, Start
from robocloud.selection.columns import Candidates, candidates
from robocloud.storage import RequestStore

logger = logging.getLogger(__name__)

# A remote reservation is a lease until the request is dispatched: if this
# cloud dies in between, the home cloud gets its robots back by itself. The
# home grants at most its own maximum.
LEASE_SECONDS = 15.0
RESERVATIONS_TTL = 0.25  # seconds a read of the store's reservations serves selections
GATHER_TTL = 0.25  # seconds the other clouds' answer serves selections of the same filter
_GATHERED_MAX = 64  # filters whose answers are kept
# What the other clouds are asked for their idle robots: at least this battery,
# and at least one of these capabilities (none: any robot).
IdleFilter = tuple[float, tuple[str, ...]]
MAX_KEPT_ACKS = 10_000  # acks of robots commanded with their reservation, until assigned


@dataclass
class View:
    """The robots one selection sees, and what the gathering noticed."""

    robots: list[RobotLike]  # other clouds' robots, as their homes sent them
    notes: list[str] = field(default_factory=list)
    gather_ms: float = 0.0


class FederationView:
    def __init__(
        self,
        cloud: str,
        store: RequestStore,
        link: RobotLink,
        overlay: Overlay | None = None,
        gather_timeout: float = 0.5,
        gather_ttl: float = GATHER_TTL,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.cloud = cloud
        self.store = store
        self.link = link
        self.overlay = overlay
        self.gather_timeout = gather_timeout
        self.gather_ttl = gather_ttl
        self._clock = clock
        # (min_battery, capabilities) -> (when asked, the answers): see remote_robots
        self._gathered: dict[IdleFilter, tuple[float, Gathered]] = {}
        self._reserved: tuple[float, set[str]] | None = None  # (when read, robot ids)
        self._recent: dict[str, float] = {}  # robots reserved here lately -> when
        self._lenders: set[str] = set()
        self._acks: dict[tuple[str, str], Ack] = {}  # (request, robot) -> its home's ack
        self._returning: dict[str, int] = {}  # robots being given back to their homes now
        self._borrowed: dict[str, float] = {}  # robots borrowed here lately -> when (clock)
        self._lock = threading.Lock()

    def lenders(self) -> list[str]:
        """The other clouds this one borrowed robots from since it started."""
        with self._lock:
            return sorted(self._lenders)

    def _borrowing_from(self, cloud: str) -> None:
        if cloud != self.cloud:
            with self._lock:
                self._lenders.add(cloud)

    # -- what a selection sees ------------------------------------------------

    def local_robots(self, held: Iterable[str] = ()) -> list[Robot]:
        """This cloud's robots; those reserved in the store (or ``held``) as ``reserved``.

        The store's reservations are read at most every ``RESERVATIONS_TTL``
        seconds: selections running at once share one read. The robots this
        process reserves meanwhile are added to that read at once (``reserve``);
        only a robot reserved by another process (another IaaS on the same
        store, a loan) can look free for that long, and its reservation is
        then refused (``reserve`` returns it as taken) and the selection runs
        again.
        """
        reserved = self._reservations() | set(held)
        return [
            robot.model_copy(update={"status": "reserved"})
            if robot.id in reserved and robot.status == "idle"
            else robot
            for robot in self.link.robots()
        ]

    def candidates(
        self, task: Task, excluded: Iterable[str] = (), others: Sequence[RobotLike] = ()
    ) -> Candidates:
        """The candidates of a selection among this cloud's robots, then ``others``.

        As ``filter_robots`` over ``local_robots(excluded)`` followed by
        ``others``, read from the link's columns: no Robot is made or copied.
        """
        return self._candidates(task, excluded, others, self._reservations())

    def candidates_at_hand(
        self, task: Task, excluded: Iterable[str] = (), others: Sequence[RobotLike] = ()
    ) -> Candidates | None:
        """``candidates`` if no read of the store is due (``RESERVATIONS_TTL``), else None.

        Without the store, this is a filter over the link's columns, cheap
        enough for the event loop, where a thread's hand-off of the GIL cost
        more than the filter (benchmarks/results/design-notes.md, filter-cost).
        The store is read on a thread: a slow store must not stall the loop.
        """
        reserved = self._reservations_at_hand()
        if reserved is None:
            return None
        return self._candidates(task, excluded, others, reserved)

    def _candidates(
        self,
        task: Task,
        excluded: Iterable[str],
        others: Sequence[RobotLike],
        reserved: set[str],
    ) -> Candidates:
        excluded = set(excluded)
        others = [r for r in others if r.id not in excluded] if excluded else others
        return candidates(self.link.columns(), task, reserved | excluded, others)

    def _reservations(self) -> set[str]:
        """The robots the store holds (read at most every ``RESERVATIONS_TTL`` seconds)."""
        at_hand = self._reservations_at_hand()
        if at_hand is not None:
            return at_hand
        now = time.monotonic()
        self._reserved = (now, set(self.store.reservations()))
        return self._and_recent(self._reserved[1], now)

    def _reservations_at_hand(self) -> set[str] | None:
        """``_reservations`` if its last read serves still, else None (no read)."""
        now = time.monotonic()
        cached = self._reserved
        if cached is None or now - cached[0] >= RESERVATIONS_TTL:
            return None
        return self._and_recent(cached[1], now)

    def _and_recent(self, read: set[str], now: float) -> set[str]:
        recent = self._recent
        if not recent:
            return read
        return read | {r for r, at in recent.items() if now - at < 2 * RESERVATIONS_TTL}

    def _reserved_now(self, ids: Iterable[str]) -> None:
        """Robots just reserved here count as reserved until every cached read has them.

        A read of the store made just before this reservation was written is
        served for up to ``RESERVATIONS_TTL``: the robots stay in ``_recent``
        for twice that. Copy on write, as selections read it from other threads.
        """
        now = time.monotonic()
        with self._lock:
            recent = {r: at for r, at in self._recent.items() if now - at < 2 * RESERVATIONS_TTL}
            recent.update((r, now) for r in ids)
            self._recent = recent

    def others_live(self) -> bool:
        """Whether a selection asks other clouds (an overlay, and another live cloud on it)."""
        return self.overlay is not None and len(self.overlay.clouds()) > 1

    def remote_robots(self, task: Task, exclude: set[str]) -> View:
        """``idle_elsewhere`` for a task: its battery and its capabilities."""
        return self.idle_elsewhere(_filter_of(task), exclude)

    def idle_elsewhere(self, wanted: IdleFilter, exclude: set[str]) -> View:
        """The idle robots of the other live clouds that answer within the timeout,
        with ``wanted``'s battery and at least one of its capabilities (any robot: none).

        The other clouds' answer to one filter (battery, capabilities) serves
        the selections that need it for ``gather_ttl`` seconds, as a read of
        the store's reservations does (``local_robots``): under load a home is
        asked a few times a second, not once per request, and a selection
        does not wait a round trip. Meanwhile a robot its home lent to
        another cloud may still be offered: its reservation is then refused
        (``reserve`` returns it as taken, and forgets every kept answer) and
        the selection runs again. The robots this cloud holds are left out
        by the caller (``candidates``), and so are those it is giving back
        right now (their homes may not have taken them back yet). An answer
        with a cloud missing is not kept, nor is one from before a cloud
        joined or left.
        """
        if self.overlay is None:
            return View([])
        kept = self._kept(wanted)
        if kept is not None:
            return self._view_of(*kept, exclude)
        asked = self._clock()
        min_battery, capabilities = wanted
        query = IdleQuery(
            origin=self.cloud, min_battery=min_battery, capabilities=list(capabilities)
        )
        gathered = self.overlay.gather_idle(query, self.gather_timeout)
        if not gathered.missing:
            with self._lock:
                if len(self._gathered) >= _GATHERED_MAX:
                    self._gathered.clear()
                self._gathered[wanted] = (asked, gathered)
        view = self._view_of(asked, gathered, exclude)
        view.gather_ms = gathered.elapsed_ms
        return view

    def must_ask(self, task: Task) -> bool:
        """Whether ``remote_robots`` would ask the other clouds (no fresh answer of theirs)."""
        if self.overlay is None or not self.others_live():
            return False
        return self._kept(_filter_of(task)) is None

    def kept_robots(self, task: Task, exclude: set[str]) -> View | None:
        """``remote_robots`` when it needs no question (no other cloud, or a fresh
        answer), else None: cheap enough for the event loop's thread."""
        if self.overlay is None or not self.others_live():
            return View([])
        kept = self._kept(_filter_of(task))
        return None if kept is None else self._view_of(*kept, exclude)

    def _view_of(self, asked: float, gathered: Gathered, exclude: set[str]) -> View:
        """The robots of an answer asked at ``asked``, less those it cannot speak for.

        Left out: ``exclude``; robots on their way back home now; and robots
        this cloud borrowed since the question was asked. The answer says they
        were idle, but they have worked since: a robot given back a moment ago
        may still be stopping, and its home refuses it, and the selection runs
        again (benchmarks/results/design-notes.md, borrowed-since).
        """
        view = View([])
        with self._lock:
            returning = set(self._returning)
            since = {r for r, at in self._borrowed.items() if at >= asked}
        for reply in gathered.replies.values():
            # A home answers for its own robots only: one it names as another
            # cloud's would be reserved and commanded there.
            view.robots += [
                r
                for r in reply.robots
                if r.cloud == reply.cloud
                and r.cloud != self.cloud
                and r.id not in exclude
                and r.id not in returning
                and r.id not in since
            ]
        if gathered.missing:
            view.notes.append(
                f"{', '.join(gathered.missing)} did not answer within "
                f"{self.gather_timeout * 1000:.0f} ms; "
                f"{'its' if len(gathered.missing) == 1 else 'their'} robots were left out"
            )
        return view

    def _kept(self, wanted: IdleFilter) -> tuple[float, Gathered] | None:
        """(when asked, the other clouds' answer to ``wanted``) if one is fresh,
        from every live cloud."""
        assert self.overlay is not None
        with self._lock:
            kept = self._gathered.get(wanted)
        if kept is None or self._clock() - kept[0] >= self.gather_ttl:
            return None
        others = set(self.overlay.clouds()) - {self.cloud}
        return kept if set(kept[1].replies) == others else None

    def _borrowed_now(self, ids: Iterable[str]) -> None:
        """Robots just lent to this cloud: no answer asked before now offers them.

        Kept for ``gather_ttl``, as long as an answer is.
        """
        now = self._clock()
        with self._lock:
            self._borrowed = {
                r: at for r, at in self._borrowed.items() if now - at < self.gather_ttl
            }
            self._borrowed.update((r, now) for r in ids)

    def forget_gathered(self) -> None:
        """Ask the other clouds again at the next selection."""
        with self._lock:
            self._gathered.clear()

    # -- reservations at each robot's home --------------------------------------

    def reserve(
        self,
        request_id: str,
        robots: Sequence[tuple[str, str]],
        commands: Mapping[str, Assign] | None = None,
    ) -> list[str]:
        """Reserve (robot, cloud) pairs, all or nothing: [] or the robots taken meanwhile.

        This cloud's robots are reserved first, then each other home's. With
        ``commands`` (robot -> its command), the last home also gets its
        robots' commands with their reservation and forwards them once it has
        lent them all: its robots are then commanded a round trip earlier,
        and ``assign`` answers with the acks it sent back (``take_ack``). Only
        the last: a home reserved before it may still be rolled back, and a
        robot must not work for a reservation that was undone.
        """
        by_cloud = _by_cloud(robots)
        order = sorted(by_cloud, key=lambda cloud: cloud != self.cloud)  # this cloud first
        done: list[str] = []
        taken: list[str] = []
        for n, cloud in enumerate(order):
            ids = by_cloud[cloud]
            if cloud == self.cloud:
                taken = self.store.reserve(request_id, ids)
                if not taken:
                    self._reserved_now(ids)
            else:
                last = n == len(order) - 1
                sent = [r for r in ids if r in commands] if commands and last else []
                taken = self._reserve_at(cloud, request_id, ids, sent, commands or {})
            if taken:
                break
            done.append(cloud)
        if taken:
            for cloud in done:
                self._release(cloud, request_id, by_cloud[cloud], "reservation rolled back")
        return taken

    def _reserve_at(
        self,
        cloud: str,
        request_id: str,
        ids: list[str],
        sent: list[str],
        commands: Mapping[str, Assign],
    ) -> list[str]:
        """Reserve robots at their home ``cloud`` (with the commands of ``sent``); the taken."""
        assert self.overlay is not None, "a remote robot without an overlay"
        self._borrowing_from(cloud)
        reservation = Reservation(
            request_id=request_id,
            robots=ids,
            lease_seconds=LEASE_SECONDS,
            dispatch=[Dispatch(robot=r, command=commands[r]) for r in sent],
        )
        try:
            reply = self.overlay.reserve(cloud, reservation)
        except RoboCloudError:
            if sent:  # the home may have lent and commanded them before the reply was lost
                self._stop_at(cloud, request_id, sent)
            self.forget_gathered()
            return ids
        taken = (reply.taken or ids) if reply.error is not None else reply.taken
        if taken:
            self.forget_gathered()  # an answer kept may still offer them
            return taken
        self._borrowed_now(ids)
        acks = {ack.robot: ack for ack in reply.acks}
        with self._lock:
            if len(self._acks) > MAX_KEPT_ACKS:  # acks no assign took (their request ended)
                self._acks.clear()
            for robot in sent:
                self._acks[(request_id, robot)] = acks.get(robot) or Ack.refuse(
                    robot, request_id, f"{cloud} sent no acknowledgement for {robot}."
                )
        return []

    def take_ack(self, request_id: str, robot: str) -> Ack | None:
        """The ack of a robot commanded with its reservation, once (None: not commanded yet)."""
        with self._lock:
            return self._acks.pop((request_id, robot), None)

    def confirm(self, request_id: str, robots: Sequence[tuple[str, str]]) -> list[str]:
        """Turn the remote leases firm once dispatched; the robots that could not be."""
        lost: list[str] = []
        for cloud, ids in _by_cloud(robots).items():
            if cloud == self.cloud or self.overlay is None:
                continue
            try:
                reply = self.overlay.confirm(cloud, Reservation(request_id=request_id, robots=ids))
                lost += (reply.taken or ids) if reply.error is not None else reply.taken
            except RoboCloudError:
                lost += ids
        return lost

    def release(
        self, request_id: str, robots: Sequence[tuple[str, str]] | None, why: str = ""
    ) -> None:
        """Give robots back to their homes (None: this cloud's hold on every robot)."""
        if robots is None:
            self.store.release(request_id, None)
            return
        for cloud, ids in _by_cloud(robots).items():
            self._release(cloud, request_id, ids, why)

    def _release(self, cloud: str, request_id: str, ids: list[str], why: str) -> None:
        if cloud == self.cloud:
            self.store.release(request_id, ids)
            return
        if self.overlay is None:
            return
        commanded = [r for r in ids if self.take_ack(request_id, r) is not None]
        if commanded:
            # Commanded with their reservation, then given back before any assign
            # (the request ended meanwhile): robots are always told.
            self._stop_at(cloud, request_id, commanded)
            ids = [r for r in ids if r not in commanded]
            if not ids:
                return
        try:
            with self._giving_back(ids):
                done = self.overlay.release(
                    cloud,
                    Release(request_id=request_id, robots=ids, why=(why or None) and why[:500]),
                )
        except RoboCloudError as error:
            # The home reconciles with us when it is back.
            logger.warning("could not release %s at %s: %s", ids, cloud, error)
            return
        if not done.ok:
            logger.warning("%s refused to release %s: %s", cloud, ids, done.error)

    # -- commands ---------------------------------------------------------------

    def assign(self, robot: str, cloud: str, command: Assign) -> Ack:
        if cloud == self.cloud:
            return self.link.assign(robot, command)
        ack = self.take_ack(command.request_id, robot)
        if ack is not None:  # commanded with its reservation
            if ack.ok and self.overlay is not None:
                self.overlay.watch(cloud, robot)
            return ack
        if self.overlay is None:
            return Ack.refuse(robot, command.request_id, f"{cloud} is not reachable.")
        ack = self.overlay.dispatch(cloud, Dispatch(robot=robot, command=command))
        if ack.ok:
            self.overlay.watch(cloud, robot)
        return ack

    def start(self, robot: str, cloud: str, request_id: str) -> Ack:
        """Protocol 1.2: a held robot starts its task's work (through its home if lent)."""
        if cloud == self.cloud:
            return self.link.start(robot, request_id)
        if self.overlay is None:
            return Ack.refuse(robot, request_id, f"{cloud} is not reachable.")
        return self.overlay.dispatch(
            cloud, Dispatch(robot=robot, command=Start(request_id=request_id))
        )

    @contextlib.contextmanager
    def _giving_back(self, robots: list[str]) -> Iterator[None]:
        """While robots go back to their home, no selection here is offered them.

        The request that held them may be over here already (so they are no
        longer held), while a kept answer of their home still lists them idle
        and the home has not yet taken them back: choosing them would only
        meet a refusal.
        """
        with self._lock:
            for robot in robots:
                self._returning[robot] = self._returning.get(robot, 0) + 1
        try:
            yield
        finally:
            with self._lock:
                for robot in robots:
                    left = self._returning.pop(robot, 1) - 1
                    if left > 0:
                        self._returning[robot] = left

    def _stop_at(self, cloud: str, request_id: str, robots: list[str]) -> None:
        """Stop robots at their home and end their loans (a cancel), logging a failure."""
        assert self.overlay is not None
        stop = Release(request_id=request_id, robots=robots, why="canceled")
        try:
            with self._giving_back(robots):
                self.overlay.cancel(cloud, stop)
        except RoboCloudError as error:
            logger.warning("could not stop %s at %s: %s", robots, cloud, error)

    def cancel(self, robot: str, cloud: str, request_id: str) -> None:
        if cloud == self.cloud:
            self.link.cancel(robot, request_id)
            return
        if self.overlay is None:
            return
        self.take_ack(request_id, robot)  # a stop after all: no assign takes it now
        self._stop_at(cloud, request_id, [robot])
        self.overlay.unwatch(cloud, robot)

    def watch(self, robot: str, cloud: str) -> None:
        if cloud != self.cloud and self.overlay is not None:
            self._borrowing_from(cloud)
            self.overlay.watch(cloud, robot)

    def unwatch(self, robot: str, cloud: str) -> None:
        if cloud != self.cloud and self.overlay is not None:
            self.overlay.unwatch(cloud, robot)

    # -- robots' reports ----------------------------------------------------------

    def ages(self) -> dict[str, float]:
        ages = dict(self.overlay.ages()) if self.overlay is not None else {}
        ages.update(self.link.ages())
        return ages

    def on_state(self, listener: StateListener) -> Callable[[], None]:
        stops = [self.link.on_state(listener)]
        if self.overlay is not None:
            stops.append(self.overlay.on_state(listener))

        def stop() -> None:
            for s in stops:
                s()

        return stop


def _filter_of(task: Task) -> IdleFilter:
    """What the other clouds' answer to a task depends on: its battery and capabilities."""
    return (task.min_battery, tuple(task.required))


def _by_cloud(robots: Sequence[tuple[str, str]]) -> dict[str, list[str]]:
    grouped: dict[str, list[str]] = defaultdict(list)
    for robot, cloud in robots:
        grouped[cloud].append(robot)
    return dict(grouped)
