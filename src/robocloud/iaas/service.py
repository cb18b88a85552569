"""The requests of one cloud's IaaS (the thesis's Virtualization Engine): their supervisor.

Each active request is an actor (``robocloud.iaas.actor``) whose rules are the
pure ``robocloud.iaas.lifecycle.decide``. This service starts the actors (for
new requests, and for unfinished ones after a restart), hands each robot's
report to the request that follows it, answers the HTTP API, and keeps every
task it starts: it awaits them when it stops and logs their errors.

The jobs beside it have owners of their own, handed to it built:

- ``robocloud.iaas.routes.RobotRoutes``: which robot follows or is claimed by
  which request, and which robots are set aside;
- ``robocloud.iaas.admission.Admission``: load shedding (a busy cloud says so);
- ``robocloud.iaas.feed.RequestFeed``: the requests' event streams;
- ``robocloud.iaas.strays.StrayRobots``: a robot working for a request that
  does not need it is told to stop.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import re
import time
from collections.abc import AsyncIterator, Callable, Coroutine
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from typing import Any, TypeVar

from pydantic import ValidationError

from robocloud.domain import Task, is_final
from robocloud.errors import (
    Conflict,
    InvalidInput,
    NotFound,
    Unavailable,
    describe_validation_errors,
)
from robocloud.federation.messages import CloudInfo
from robocloud.federation.view import FederationView
from robocloud.fleet.messages import State
from robocloud.iaas import lifecycle as lc
from robocloud.iaas.actor import RequestActor, Selector, Shell
from robocloud.iaas.admission import Admission
from robocloud.iaas.config import Settings
from robocloud.iaas.feed import RequestFeed, Updates
from robocloud.iaas.metrics import IaasMetrics
from robocloud.iaas.owned import spawn_owned
from robocloud.iaas.routes import RobotRoutes
from robocloud.iaas.selector import SelectionPool, SelectorSettings
from robocloud.iaas.store_writes import StoreWrites
from robocloud.iaas.strays import StrayRobots
from robocloud.selection.pipeline import select_problem
from robocloud.selection.problem import CoalitionProblem
from robocloud.selection.result import SelectionResult
from robocloud.storage import RequestRecord, RequestStore, StoreUnavailable

log = logging.getLogger(__name__)

T = TypeVar("T")
REQUEST_ID = re.compile(r"^req-[a-z2-7]{12}$")
IO_THREADS = 64  # blocking calls at once that wait on the network: robots' acks, other clouds
# Store calls get threads of their own, few: SQLite writes one at a time anyway,
# and many threads contending for the GIL while one holds the write lock made
# every write wait (benchmarks/results/design-notes.md, store-threads).
STORE_THREADS = 4
UNDECIDED = frozenset({"received", "selecting"})


class RequestService:
    """Runs every request of one cloud from ``received`` to a final state."""

    def __init__(
        self,
        settings: Settings,
        store: RequestStore,
        view: FederationView,
        clock: Callable[[], float] = time.time,
        selector: Selector | None = None,
        metrics: IaasMetrics | None = None,
        routes: RobotRoutes | None = None,
        home_info: Callable[[], CloudInfo] | None = None,
        lent_for: Callable[[str], str | None] = lambda robot: None,
    ) -> None:
        self.settings = settings
        self.metrics = metrics or IaasMetrics()
        self.store = store
        self.view = view
        self.link = view.link
        self.clock = clock
        self.routes = routes or RobotRoutes(settings.set_aside_for, clock)
        self.feed = RequestFeed()
        self.metrics.observe_streams(self.feed.following)
        # This cloud's presence summary (its Home's) and its loans.
        self.home_info: Callable[[], CloudInfo] = home_info or (
            lambda: CloudInfo(cloud=settings.cloud, robots=len(self.link.robots()), idle=0)
        )
        self.lent_for = lent_for
        self._io = ThreadPoolExecutor(IO_THREADS, thread_name_prefix=f"iaas-{settings.cloud}")
        self._store_threads = ThreadPoolExecutor(
            STORE_THREADS, thread_name_prefix=f"store-{settings.cloud}"
        )
        # Writes go in turns, several in one transaction (iaas/store_writes.py):
        # one turn at a time on a local store, whose writers take turns anyway
        # (SQLite); on PostgreSQL each write of a turn is its own transaction,
        # and several turns run side by side.
        self.store_write = StoreWrites(
            store,
            self._store_threads,
            self.store_failed,
            takers=1 if store.local_reads else STORE_THREADS,
        )
        self._pool: SelectionPool | None = None
        if selector is None and settings.selection_workers > 0:
            self._pool = SelectionPool(
                SelectorSettings(
                    optimizer=settings.optimizer,
                    seed=settings.seed,
                    budget_s=settings.selection_budget,
                    workers=settings.selection_workers,
                    max_workers=most_workers(settings.selection_workers),
                    memory_mb=settings.selection_memory_mb,
                ),
                self.blocking,
            )
            selector = self._pool
        # As many selections at once as the pool has workers at most (two
        # without a pool): a request waits for its turn before it reads its
        # candidates, not after.
        self._selection_turns = asyncio.Semaphore(
            self._pool.settings.max_workers if self._pool is not None else 2
        )
        self._shell = Shell(
            store=store,
            view=view,
            selector=selector or self._select_in_thread,
            rules=lc.Rules(
                offline_after=settings.offline_after,
                attempts=settings.reselect_attempts,
                time_scale=settings.time_scale,
                overrun_ratio=settings.overrun_ratio,
                overrun_min=settings.overrun_min,
                stall_after=settings.stall_after,
            ),
            blocking=self.blocking,
            store_write=self.store_write,
            publish=self._publish,
            routes=self.routes,
            wall=clock,
            metrics=self.metrics,
            selection_turn=lambda: self._selection_turns,
        )
        self.rules = self._shell.rules  # the watchdog's rule, shared with the missions
        self.admission = Admission(
            settings.max_waiting, settings.busy_after, self.metrics, self._shell.mono
        )
        self.strays = StrayRobots(
            settings.cloud,
            self.link,
            self.routes,
            lambda robot: self.lent_for(robot),
            self.blocking,
            self._spawn,
            self.metrics,
        )
        self._actors: dict[str, RequestActor] = {}
        self._tasks: set[asyncio.Task[Any]] = set()  # actors and background work
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop_listening: Callable[[], None] = lambda: None

    # -- life of the service -------------------------------------------------------

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        if self._pool is not None:
            self._pool.start()
        self._stop_listening = self.view.on_state(self._state_from_thread)
        await self._recover()

    async def stop(self) -> None:
        self._stop_listening()
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self.feed.close()
        if self._pool is not None:
            self._pool.close()
        self._io.shutdown(wait=False, cancel_futures=True)
        self._store_threads.shutdown(wait=False, cancel_futures=True)

    async def blocking(self, function: Callable[..., T], *args: Any) -> T:
        """``function(*args)`` on the IaaS's I/O threads (robots, other clouds)."""
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self._io, partial(function, *args))

    async def in_store(self, function: Callable[..., T], *args: Any) -> T:
        """``function(*args)`` on the store's threads (a failure counted in the metrics).

        For reads; writes go through ``store_write``, in turns.
        """
        loop = asyncio.get_running_loop()
        try:
            return await loop.run_in_executor(self._store_threads, partial(function, *args))
        except StoreUnavailable:
            self.store_failed(function)
            raise

    def store_failed(self, function: Callable[..., Any]) -> None:
        self.metrics.store_errors.labels(getattr(function, "__name__", "call")).inc()

    def _spawn(self, work: Coroutine[Any, Any, Any], what: str) -> asyncio.Task[Any]:
        """A task this service owns: awaited in ``stop``, its error logged."""
        return spawn_owned(self._tasks, work, what, log)

    def _start(
        self,
        record: RequestRecord,
        life: lc.Life,
        start: lc.Start,
        posted_at: float | None = None,
    ) -> None:
        actor = RequestActor(self._shell, life, record, posted_at)
        self._actors[record.id] = actor
        task = self._spawn(actor.run(start), f"the actor of request {record.id}")

        def ended(_: asyncio.Task[Any]) -> None:
            if self._actors.get(record.id) is actor:
                del self._actors[record.id]
                self.admission.decided(record.id)
            self.routes.forget(record.id)

        task.add_done_callback(ended)

    async def _select_in_thread(self, problem: CoalitionProblem, task: Task) -> SelectionResult:
        result: SelectionResult = await asyncio.to_thread(
            select_problem,
            problem,
            task,
            self.settings.optimizer,  # type: ignore[arg-type]
            seed=self.settings.seed,
            budget_s=self.settings.selection_budget,
            ranking=False,  # the IaaS keeps none
        )
        return result

    # -- what the HTTP API calls ----------------------------------------------------

    async def submit(
        self, application: str, task: Task, label: str | None, idempotency_key: str | None
    ) -> RequestRecord:
        posted_at = self._shell.mono()
        task_json = task.model_dump(mode="json")
        if idempotency_key is not None and self.admission.busy(posted_at) is not None:
            # A retry of a request this cloud has (its answer was lost, say) is
            # answered with it even when busy: nothing new would be stored.
            existing = await self.in_store(
                self.store.by_idempotency_key, application, idempotency_key
            )
            if existing is not None:
                return _same_body(existing, task_json, label, idempotency_key)
        self.admission.admit(posted_at)
        record, created = await self.store_write(
            self.store.create_request, application, task_json, label, idempotency_key
        )
        if not created:
            return _same_body(record, task_json, label, idempotency_key)
        life = lc.Life(request_id=record.id, task=task, rules=self._shell.rules)
        self.metrics.entered(record.state)
        self.admission.waits(record.id, posted_at)
        self._start(record, life, lc.Start(), posted_at)
        return record

    async def get(self, application: str, request_id: str) -> RequestRecord:
        if not REQUEST_ID.fullmatch(request_id):
            raise NotFound(f"there is no request {request_id!r}.", request_id)
        if self.store.local_reads:
            # The two thread hand-offs, not the read, made the slow tail
            # (benchmarks/results/design-notes.md, get-on-loop).
            try:
                record = self.store.get(request_id, application)
            except StoreUnavailable:
                self.store_failed(self.store.get)
                raise
        else:
            record = await self.in_store(self.store.get, request_id, application)
        if record is None:
            raise NotFound(f"there is no request {request_id!r}.", request_id)
        return record

    async def cancel(self, application: str, request_id: str) -> RequestRecord:
        record = await self.get(application, request_id)
        actor = self._actors.get(request_id)
        if actor is not None:
            reply: asyncio.Future[RequestRecord] = asyncio.get_running_loop().create_future()
            actor.post(lc.CancelAsked(), reply)
            try:
                record = await asyncio.wait_for(asyncio.shield(reply), self.settings.cancel_timeout)
            except TimeoutError:
                raise Unavailable(
                    f"the cancel of request {request_id} is not stored yet (the store may be "
                    "unavailable); it will be carried out, ask again to see it."
                ) from None
        if record.state == "canceled":
            return record
        if is_final(record.state):
            raise Conflict(
                f"request {request_id} is already {record.state}; only a request that is "
                "not finished can be canceled."
            )
        if actor is not None:
            raise Unavailable(f"the cancel of request {request_id} could not be stored; ask again.")
        # Not run by this process (it is stopping): store it directly.
        record = await self.store_write(
            self.store.transition, request_id, "canceled", None, "canceled by the application"
        )
        self._publish(record)
        return record

    def active_states(self) -> list[str]:
        """The state of each request an actor carries out now (any thread: a snapshot)."""
        return [actor.record.state for actor in list(self._actors.values())]

    def robot_statuses(self) -> list[tuple[str, str]]:
        """(cloud, status) of each robot of this cloud, as ``GET /v1/robots`` shows it."""
        try:
            held = self.store.reservations()
        except StoreUnavailable:
            self.store_failed(self.store.reservations)
            held = {}
        return [
            (
                robot.cloud,
                "reserved" if robot.status == "idle" and robot.id in held else robot.status,
            )
            for robot in self.link.robots()
        ]

    def progress_of(self, robot_id: str) -> tuple[str, float] | None:
        member = self._member(robot_id)
        return (member.phase, member.progress) if member is not None else None

    def owner_of(self, request_id: str) -> str | None:
        """The application of a request this process carries out now, or None."""
        actor = self._actors.get(request_id)
        return actor.record.application if actor is not None else None

    def request_of(self, robot_id: str) -> str | None:
        return self.routes.request_of(robot_id)

    def coalition_robots(self, request_id: str) -> list[str]:
        """The robots working for a request now (what the homes of remote robots ask)."""
        return self.routes.robots_of(request_id)

    def current(self, request_id: str) -> lc.Life | None:
        """The live life of an active request (its members' phases), if this process runs it."""
        actor = self._actors.get(request_id)
        return actor.life if actor is not None else None

    def events(
        self, application: str, request_id: str, updates: Updates
    ) -> AsyncIterator[RequestRecord]:
        """The request now, then each change (``updates``: ``feed.subscribe``), until final."""
        return self.feed.follow(updates, lambda: self.get(application, request_id))

    def loan_ended(self, request_id: str, robot: str, home: str, why: str) -> None:
        """A robot's home ended its loan to one of our requests on its own (any thread).

        ``robocloud.federation.home.OriginStatus``: maybe called twice for one loan.
        The request's history says so, and a robot still in its coalition is
        treated as failed (replaced, or the request fails).
        """
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self._loan_ended, request_id, robot, home, why)

    def _loan_ended(self, request_id: str, robot: str, home: str, why: str) -> None:
        actor = self._actors.get(request_id)
        if actor is not None:
            actor.post(lc.LoanEnded(robot, home, why))
            return

        async def note() -> None:  # the request is over: only its history learns it
            with contextlib.suppress(NotFound):
                record = await self.store_write(
                    self.store.add_event, request_id, lc.loan_ended_note(robot, home, why)
                )
                self._publish(record)

        self._spawn(note(), f"noting the end of the loan of {robot}")

    # -- followers, routes and robots' reports ------------------------------------------

    def _publish(self, record: RequestRecord) -> None:
        if record.state not in UNDECIDED:
            self.admission.decided(record.id)
        self.feed.publish(record)

    def _post(self, request_id: str, event: lc.Event) -> None:
        actor = self._actors.get(request_id)
        if actor is not None:
            actor.post(event)

    def _member(self, robot_id: str) -> lc.Member | None:
        request_id = self.routes.request_of(robot_id)
        actor = self._actors.get(request_id) if request_id is not None else None
        if actor is None:
            return None
        for member in actor.life.followed():
            if member.robot == robot_id:
                return member
        return None

    def _state_from_thread(self, state: State) -> None:
        """Called on Zenoh's threads for every state message; hops to the loop when it matters."""
        loop = self._loop
        if loop is None:
            return
        if self.routes.request_of(state.id) is not None or self.strays.may_be_stray(
            state, self.settings.cloud
        ):
            loop.call_soon_threadsafe(self._on_state, state)

    def _on_state(self, state: State) -> None:
        request_id = self.routes.request_of(state.id)
        if request_id is not None:
            self._post(request_id, report_for(state, request_id))
        self.strays.check(state)

    # -- restart ------------------------------------------------------------------------

    async def _recover(self) -> None:
        """Resume what a previous run of this IaaS left unfinished."""
        for record in await self.in_store(self.store.active):
            try:
                task = Task.model_validate(record.task)
            except ValidationError as error:
                # Stored by another version, or edited by hand: say so, and go on.
                why = describe_validation_errors(error.errors(), "task").message
                log.error("request %s cannot be resumed: %s", record.id, why)
                with contextlib.suppress(Conflict, NotFound):
                    await self.store_write(
                        self.store.transition,
                        record.id,
                        "failed",
                        f"it could not be resumed after a restart: its stored {why}",
                    )
                continue
            life = lc.life_of(record.id, task, record.state, record.selection, self._shell.rules)
            if record.state in UNDECIDED:
                # Waiting for its robots again, from now: counted by ``busy``.
                self.admission.waits(record.id)
            self._start(record, life, lc.Start(resumed=True))


def most_workers(kept: int, cores: int | None = None) -> int:
    """How many selection workers the pool may run when all ``kept`` are busy.

    Up to twice as many, but not past the machine's cores (unless ``kept``
    already is): more selections at once than cores only share them, each
    slower, and more of them pick the same robot
    (benchmarks/results/design-notes.md, selection-workers).
    """
    cores = cores if cores is not None else (os.cpu_count() or 1)
    return max(kept, min(2 * kept, cores))


def report_for(state: State, request_id: str) -> lc.RobotReport:
    """A robot's state, read for one request."""
    task, last = state.task, state.last_task
    ours = task if task is not None and task.request_id == request_id else None
    last = last if last is not None and last.request_id == request_id else None
    return lc.RobotReport(
        robot=state.id,
        status=state.status,
        battery=state.battery,
        phase=ours.phase if ours is not None else None,
        progress=ours.progress if ours is not None else 0.0,
        last_phase=last.phase if last is not None else None,
        reason=said.reason if (said := ours or last) is not None else None,
    )


def _same_body(
    record: RequestRecord, task_json: dict[str, Any], label: str | None, key: str | None
) -> RequestRecord:
    """The request an Idempotency-Key was used for, if the body is the same; else a 422."""
    if record.task != task_json or record.label != label:
        raise InvalidInput(
            f"Idempotency-Key {key!r} was already used for another "
            f"request ({record.id}) with a different body; a new request needs a "
            "new key.",
            "Idempotency-Key",
        )
    return record
