"""One actor per active request: an asyncio task with an inbox that carries out ``decide``.

The actor is the thin shell around ``robocloud.iaas.lifecycle``: it takes one
event at a time from its inbox (robot reports, the results of its own
operations, the application's cancel, a tick about twice a second), asks
``decide`` what to do, and carries out the effects in order. Effects that wait
on other parties (a selection, reservations, the robots' acknowledgements,
stop commands) run as operations the actor owns: their results come back
through the inbox, so a cancel is handled while a selection is still running.
The actor ends once its request is final and none of its operations is left;
an error it cannot carry on from fails the request with a reason.

Writes to the store are retried while the store is unavailable (with a
growing pause, up to 5 s): a state change is never skipped, only delayed.

Why one long file: each effect of ``decide`` is carried out here, next to
the operation it starts; the supervisor (``service.py``) and the rules
(``lifecycle.py``) are elsewhere.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
import time
from collections import deque
from collections.abc import Awaitable, Callable, Sequence
from contextlib import AbstractAsyncContextManager
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar

from robocloud.domain import Task, is_final
from robocloud.errors import Conflict, Unavailable
from robocloud.federation.view import FederationView, View
from robocloud.fleet.messages import Ack
from robocloud.fleet.messages import Assign as AssignCommand
from robocloud.iaas import lifecycle as lc
from robocloud.iaas.metrics import IaasMetrics
from robocloud.iaas.routes import RobotRoutes
from robocloud.selection.columns import Candidates
from robocloud.selection.problem import CoalitionProblem
from robocloud.selection.result import SelectionResult
from robocloud.storage import RequestRecord, RequestStore

log = logging.getLogger(__name__)

T = TypeVar("T")
TICK = 0.5  # seconds between two ticks of an actor
COLLISION_PAUSE = 0.02  # seconds, times the attempt: the most a selection waits after a collision
STORE_RETRY_MAX = 5.0  # seconds, the longest pause between two tries of a store write


class Selector(Protocol):
    """Runs the selection pipeline for a task over its candidates (already filtered)."""

    def __call__(self, problem: CoalitionProblem, task: Task) -> Awaitable[SelectionResult]: ...


@dataclass
class Shell:
    """What every actor of one IaaS shares: the I/O parts and the supervisor's hooks."""

    store: RequestStore
    view: FederationView
    selector: Selector
    rules: lc.Rules
    blocking: Callable[..., Awaitable[Any]]  # a blocking call on the IaaS's I/O threads
    store_write: Callable[..., Awaitable[Any]]  # a store write, made in the next turn
    publish: Callable[[RequestRecord], None]
    routes: RobotRoutes  # which robot follows or is claimed by which request
    wall: Callable[[], float] = time.time
    mono: Callable[[], float] = time.monotonic
    metrics: IaasMetrics = field(default_factory=IaasMetrics)
    # A turn at the selector: the candidates are read once the selection can
    # start, not before a wait for a free worker (``RequestActor._select``).
    selection_turn: Callable[[], AbstractAsyncContextManager[Any]] = contextlib.nullcontext


Reply = asyncio.Future[RequestRecord]


class RequestActor:
    def __init__(
        self,
        shell: Shell,
        life: lc.Life,
        record: RequestRecord,
        posted_at: float | None = None,
    ) -> None:
        self.shell = shell
        # When its POST came (``shell.mono``), until it is dispatched: None for a
        # request resumed after a restart.
        self.posted_at = posted_at
        self.life = life
        self.record = record
        self.inbox = Inbox()
        self._ops: set[asyncio.Task[None]] = set()
        # The other clouds' idle robots, asked for before the effects ahead of
        # the selection are carried out (``_ask_others_early``).
        self._early: tuple[lc.Select, asyncio.Task[View]] | None = None
        self.closed = False  # its loop has ended: what is posted now is answered at once

    @property
    def request_id(self) -> str:
        return self.life.request_id

    def post(self, event: lc.Event, reply: Reply | None = None) -> None:
        """Hand the actor an event (on the event loop's thread)."""
        if self.closed:
            # Between the end of its loop and its removal from the service, a
            # cancel would otherwise wait for an answer that never comes.
            if reply is not None:
                _answer(reply, self.record)
            return
        self.inbox.put_nowait((event, reply))

    async def run(self, start: lc.Start) -> None:
        replies: list[Reply] = []
        try:
            await self._handle(start)
            next_tick = self.shell.mono() + TICK
            while not (self.life.final and not self._ops and self.inbox.empty()):
                wait = max(0.0, next_tick - self.shell.mono())
                event, reply = await self.inbox.next(wait)
                if event is not None:
                    await self._handle(event)
                if reply is not None:
                    replies.append(reply)
                    _answer(reply, self.record)
                if self.shell.mono() >= next_tick:
                    next_tick = self.shell.mono() + TICK
                    if not isinstance(event, lc.Tick):
                        await self._handle(lc.Tick())
        except asyncio.CancelledError:
            raise
        except Exception as error:
            log.exception("request %s: its actor failed", self.request_id)
            await self._crash(error)
        finally:
            self.closed = True
            if self._early is not None:
                self._early[1].cancel()
            for op in list(self._ops):
                op.cancel()
            await asyncio.gather(*self._ops, return_exceptions=True)
            while not self.inbox.empty():
                _, reply = self.inbox.get_nowait()
                if reply is not None:
                    _answer(reply, self.record)

    # -- events and effects ----------------------------------------------------------

    async def _handle(self, event: lc.Event) -> None:
        now = lc.Now(self.shell.mono(), self.shell.wall())
        self.life, effects = lc.decide(self.life, event, now)
        self._ask_others_early(effects)
        for effect in effects:
            await self._carry_out(effect)

    def _ask_others_early(self, effects: Sequence[lc.Effect]) -> None:
        """Start gathering the other clouds' idle robots for a first selection at once.

        A new request's first effects are the write of its ``selecting`` state,
        then the selection. The question to the other clouds only reads, and
        its answer travels while this cloud writes: it is asked first, and the
        selection takes the answer. Only when a question is needed: not for a
        cloud alone, nor while the other clouds' answer to the same filter is
        fresh (``FederationView.remote_robots``).
        """
        view = self.shell.view
        for effect in effects:
            if (
                isinstance(effect, lc.Select)
                and effect.attempt == 1
                and view.must_ask(effect.task)
            ):
                if self._early is not None:
                    self._early[1].cancel()
                task = effect.task
                gathering = asyncio.ensure_future(
                    self.shell.blocking(view.remote_robots, task, set(effect.exclude))
                )
                # Retrieved, so an answer nobody waits for (a cancel came) logs nothing.
                gathering.add_done_callback(lambda g: g.cancelled() or g.exception())
                self._early = (effect, gathering)
                return

    async def _crash(self, error: Exception) -> None:
        """Fail the request with the error's sentence; every effect is tried, none may raise."""
        now = lc.Now(self.shell.mono(), self.shell.wall())
        self.life, effects = lc.decide(
            self.life, lc.Crashed(str(error) or type(error).__name__), now
        )
        for effect in effects:
            try:
                await asyncio.wait_for(self._carry_out(effect), 30)
            except Exception:
                log.exception("request %s: cleaning up after a failure failed", self.request_id)

    async def _carry_out(self, effect: lc.Effect) -> None:
        shell, rid = self.shell, self.request_id
        match effect:
            case lc.Commit(state, reason, detail, selection):
                self.record = await self._transition(
                    state, reason, detail, dict(selection) if selection is not None else None
                )
                shell.metrics.entered(state)
                if state == "dispatched" and self.posted_at is not None:
                    shell.metrics.dispatch_seconds.observe(shell.mono() - self.posted_at)
                    self.posted_at = None
                shell.publish(self.record)
            case lc.Note(detail):
                self.record = await self._note(detail)
                shell.publish(self.record)
            case lc.SaveSelection(selection):
                self.record = await self._write(shell.store.set_selection, rid, dict(selection))
                shell.publish(self.record)
            case lc.Publish():
                shell.publish(self.record)
            case lc.Select():
                self._operate(lambda: self._select(effect), "selection")
            case lc.Reserve(robots):
                commands = self._commands_ahead()
                self._operate(lambda: self._reserve(robots, commands), "reservation")
            case lc.Assign(members, task):
                self._operate(lambda: self._assign(members, task), "dispatch")
            case lc.Remind(members, task):
                self._operate(lambda: self._remind(members, task), "reminder")
            case lc.StopRobots(robots):
                shell.metrics.stops.labels("request").inc(len(robots))
                self._operate(lambda: self._stop(robots), "stop")
            case lc.Confirm(robots):
                here = shell.view.cloud
                # Only loans turn firm: this cloud's own robots need no thread.
                lost = (
                    await shell.blocking(shell.view.confirm, rid, list(robots))
                    if any(cloud != here for _, cloud in robots)
                    else []
                )
                if lost:
                    await self._carry_out(
                        lc.Note(
                            f"the leases on {', '.join(lost)} could not be made firm; "
                            "their homes may give them away"
                        )
                    )
            case lc.Release(robots, why):
                if is_final(self.record.state):
                    # The final state's transaction released this cloud's robots.
                    robots = tuple(p for p in robots if p[1] != shell.view.cloud)
                if robots:
                    await shell.blocking(shell.view.release, rid, list(robots), why)
            case lc.ReleaseAll():
                await self._write(shell.store.release, rid, None)
            case lc.Follow(robots):
                for robot, cloud in robots:
                    if shell.routes.follow(rid, robot):
                        shell.view.watch(robot, cloud)
            case lc.Unfollow(robots):
                for robot, cloud in robots:
                    if shell.routes.unfollow(rid, robot):
                        shell.view.unwatch(robot, cloud)
            case lc.Unclaim(robots):
                shell.routes.unclaim(rid, (robot for robot, _ in robots))
            case lc.RobotFailed(robot, _, cause, why):
                shell.metrics.robot_failures.labels(cause).inc()
                if cause in lc.STRIKING:
                    aside = shell.routes.strike(robot, why)
                    if aside is not None:
                        shell.metrics.set_aside.inc()
                        log.warning(
                            "robot %s is set aside for %.0f s: %s",
                            robot, shell.routes.cooldown, aside.why,
                        )
            case lc.RobotDone(robot):
                shell.routes.behaved(robot)

    def _operate(self, work: Callable[[], Awaitable[lc.Event | None]], what: str) -> None:
        """Run ``work()`` as an operation of this actor; its result comes back as an event.

        Operations only read the store or write it all or nothing, so one
        that finds the store unavailable runs again once it may be back.
        """

        async def operation() -> None:
            try:
                event = await self._again_while_unavailable(work, what)
            except asyncio.CancelledError:
                raise
            except Conflict as error:
                event = None
                log.info("request %s moved on during its %s: %s", self.request_id, what, error)
            except Exception as error:
                log.exception("request %s: its %s failed", self.request_id, what)
                event = lc.Crashed(f"{what} failed: {error}")
            finally:
                self._ops.discard(task)
            self.inbox.put_nowait((event, None))  # None still wakes the actor

        task = asyncio.ensure_future(operation())
        self._ops.add(task)

    async def _write(self, method: Callable[..., T], *args: Any) -> T:
        """A store write, tried again while the store is unavailable."""
        return await self._again_while_unavailable(
            lambda: self.shell.store_write(method, *args), "store write"
        )

    async def _transition(
        self,
        state: str,
        reason: str | None,
        detail: str | None,
        selection: dict[str, Any] | None,
    ) -> RequestRecord:
        """The request's move to ``state``, stored once (``_write_once``)."""
        was = self.record.state
        return await self._write_once(
            lambda found: found.state == state != was,
            self.shell.store.transition, self.request_id, state, reason, detail, selection,
        )

    async def _note(self, detail: str) -> RequestRecord:
        """A line of the request's history, stored once (``_write_once``)."""

        def count(record: RequestRecord) -> int:
            return sum(1 for h in record.history if h.kind == "event" and h.detail == detail)

        before = count(self.record)
        return await self._write_once(
            lambda found: count(found) > before,
            self.shell.store.add_event, self.request_id, detail,
        )

    async def _write_once(
        self, stored: Callable[[RequestRecord], bool], method: Callable[..., RequestRecord],
        *args: Any,
    ) -> RequestRecord:
        """A write of this request, tried again while the store is unavailable, stored once.

        A try that failed as unavailable may have been stored all the same: the
        connection broke after the commit, before its answer (seen with
        PostgreSQL behind a proxy that was cut). Tried again, a move would be
        refused as one to the state the request is in, and a note would be
        written twice. So after such a try the request is read first, and when
        ``stored`` finds the write there, that is the answer. This actor alone
        writes its request while it lives (a cancel goes through it; the
        service notes a loan's end only for a request with no actor), so what
        it finds is its own.
        """
        shell, rid = self.shell, self.request_id
        unsure = False

        async def attempt() -> RequestRecord:
            nonlocal unsure
            if unsure:
                found = await shell.blocking(shell.store.get, rid)
                if found is not None and stored(found):
                    log.info("request %s: a write that lost its answer was stored", rid)
                    return found  # type: ignore[no-any-return]
            try:
                record: RequestRecord = await shell.store_write(method, *args)
            except Unavailable:
                unsure = True
                raise
            return record

        return await self._again_while_unavailable(attempt, "store write")

    async def _again_while_unavailable(self, work: Callable[[], Awaitable[T]], what: str) -> T:
        pause = 0.2
        while True:
            try:
                return await work()
            except Unavailable as error:
                log.warning(
                    "request %s: %s; its %s runs again in %.1f s",
                    self.request_id,
                    error,
                    what,
                    pause,
                )
                await asyncio.sleep(pause)
                pause = min(pause * 2, STORE_RETRY_MAX)

    # -- operations ---------------------------------------------------------------

    async def _select(self, effect: lc.Select) -> lc.Event:
        shell = self.shell
        if effect.attempt > 1:
            # Requests that collided pick again at different moments.
            await asyncio.sleep(random.uniform(0.0, COLLISION_PAUSE * effect.attempt))
        exclude = set(effect.exclude)
        early, self._early = self._early, None
        if early is not None and early[0] is effect:
            gathered = await early[1]
        else:
            if early is not None:
                early[1].cancel()
            # No question to ask (no other cloud, or their fresh answer): no thread.
            kept = shell.view.kept_robots(effect.task, exclude)
            if kept is None:
                gathered = await shell.blocking(shell.view.remote_robots, effect.task, exclude)
            else:
                gathered = kept
        if gathered.gather_ms > 0:  # other clouds were asked
            shell.metrics.overlay_seconds.labels("gather").observe(gathered.gather_ms / 1000)
        # Read the candidates only when the selection can start at once, and
        # claim the chosen robots before the turn ends: candidates read before
        # a wait for a worker were stale by then, and selections that waited
        # together picked the same robots (benchmarks/results/design-notes.md,
        # selection-turn).
        async with shell.selection_turn():
            left_out = exclude | shell.routes.held()
            # On the loop when no read of the store is due: a thread's hand-off
            # cost more than the filter (benchmarks/results/design-notes.md,
            # filter-on-loop).
            found = shell.view.candidates_at_hand(effect.task, left_out, gathered.robots)
            if found is None:
                found = await shell.blocking(
                    shell.view.candidates, effect.task, left_out, gathered.robots
                )
            started = shell.mono()
            result = await shell.selector(found.problem, effect.task)
            shell.metrics.selection_seconds.observe(shell.mono() - started)
            if result.chosen is not None:
                # Other selections see them as taken until the reservation is done.
                shell.routes.claim(self.request_id, result.chosen.robots)
        selection = selection_json(result)
        notes = (*gathered.notes, *([result.note] if result.note else []))
        if result.chosen is None:
            return lc.Selected(None, selection, result.reason, notes, result.complete)
        chosen = members_for(found, result.chosen.robots, effect.offset)
        return lc.Selected(chosen, selection, None, notes, result.complete)

    def _commands_ahead(self) -> dict[str, AssignCommand]:
        """The commands of the robots being reserved at other clouds, sent with the reservation.

        A home forwards them as soon as it has lent its robots, a round trip
        before the ``Assign`` that follows ``Reserved`` would; the acks come
        back with the reservation and ``Assign`` takes them
        (``FederationView.reserve``). The life cycle is the same: a robot
        commanded so and then given back is stopped.
        """
        attempt, here = self.life.attempt, self.shell.view.cloud
        if attempt is None or self.life.final:
            return {}
        return {
            m.robot: command_for(self.request_id, m, attempt.task)
            for m in attempt.chosen
            if m.cloud != here
        }

    async def _reserve(self, robots: lc.Pairs, commands: dict[str, AssignCommand]) -> lc.Event:
        shell = self.shell
        # This cloud's robots only: a store write, made with the others of its
        # turn; with another cloud's, a thread waits on the overlay.
        local = all(cloud == shell.view.cloud for _, cloud in robots)
        call = shell.store_write if local else shell.blocking
        try:
            taken = await call(shell.view.reserve, self.request_id, list(robots), commands)
        except Conflict:
            return lc.Reserved(tuple(r for r, _ in robots))  # the request is over
        return lc.Reserved(tuple(taken))

    async def _assign(self, members: Sequence[lc.Member], task: Task) -> lc.Event:
        view = self.shell.view

        async def ack_of(m: lc.Member) -> Ack:
            # A robot commanded with its reservation: its home's ack is here already.
            ack = view.take_ack(self.request_id, m.robot) if m.cloud != view.cloud else None
            if ack is not None:
                return ack
            command = command_for(self.request_id, m, task)
            return await self._timed("assign", m.cloud, view.assign, m.robot, m.cloud, command)

        acks = await asyncio.gather(*(ack_of(m) for m in members))
        return lc.Acked(
            {
                m.robot: ack.error or "no reason given"
                for m, ack in zip(members, acks, strict=True)
                if not ack.ok
            },
            frozenset(ack.robot for ack in acks if ack.unanswered),
        )

    async def _remind(self, members: Sequence[lc.Member], task: Task) -> None:
        """The assign again, for robots back from a silence; their states say the rest."""
        view = self.shell.view
        await asyncio.gather(
            *(
                self._timed(
                    "assign", m.cloud, view.assign, m.robot, m.cloud,
                    command_for(self.request_id, m, task),
                )
                for m in members
            )
        )

    async def _stop(self, robots: lc.Pairs) -> None:
        view = self.shell.view
        await asyncio.gather(
            *(
                self._timed("stop", cloud, view.cancel, robot, cloud, self.request_id)
                for robot, cloud in robots
            )
        )

    async def _timed(self, command: str, cloud: str, call: Callable[..., T], *args: Any) -> T:
        """A command to one robot, its wait measured: an ack here, the overlay for a loan."""
        shell = self.shell
        started = shell.mono()
        try:
            result: T = await shell.blocking(call, *args)
            return result
        finally:
            elapsed = shell.mono() - started
            if cloud == shell.view.cloud:
                shell.metrics.ack_seconds.labels(command).observe(elapsed)
            else:
                operation = "dispatch" if command == "assign" else "cancel"
                shell.metrics.overlay_seconds.labels(operation).observe(elapsed)


Letter = tuple[lc.Event | None, Reply | None]  # an event (None: only wake up), a reply


class Inbox:
    """An actor's inbox: what was posted, in order; ``next`` waits at most until the tick.

    A request's actor waits on its inbox a dozen times in its life. On a
    plain ``asyncio.Queue`` each wait was ``wait_for(queue.get(), ...)``: a
    task, a timer and callbacks. Here it is one future and one timer, and
    none when a letter is waiting already.
    """

    def __init__(self) -> None:
        self._letters: deque[Letter] = deque()
        self._waiter: asyncio.Future[None] | None = None

    def put_nowait(self, letter: Letter) -> None:
        self._letters.append(letter)
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    def empty(self) -> bool:
        return not self._letters

    def get_nowait(self) -> Letter:
        return self._letters.popleft()

    async def next(self, wait: float) -> Letter:
        """The first letter, or a ``Tick`` when none came within ``wait`` seconds."""
        if not self._letters:
            loop = asyncio.get_running_loop()
            self._waiter = waiter = loop.create_future()
            timer = loop.call_later(wait, _wake, waiter)
            try:
                await waiter
            finally:
                timer.cancel()
                self._waiter = None
            if not self._letters:
                return lc.Tick(), None
        return self._letters.popleft()


def _wake(waiter: asyncio.Future[None]) -> None:
    if not waiter.done():
        waiter.set_result(None)


def _answer(reply: Reply, record: RequestRecord) -> None:
    if not reply.done():
        reply.set_result(record)


def command_for(request_id: str, member: lc.Member, task: Task) -> AssignCommand:
    return AssignCommand(
        request_id=request_id,
        location=list(task.location),
        capabilities=list(member.capabilities),
        execution=task.execution,
    )


def members_for(
    found: Candidates, ids: Sequence[str], offset: float = 0.0
) -> tuple[lc.Member, ...]:
    """The chosen robots with the capabilities each brings, its t_i and c_i."""
    problem = found.problem
    index = {robot: i for i, robot in enumerate(problem.ids)}
    members = []
    for robot in ids:
        i = index[robot]
        members.append(
            lc.Member(
                robot=robot,
                cloud=found.clouds[i],
                capabilities=tuple(
                    name for k, name in enumerate(problem.capabilities) if problem.uses[i, k]
                ),
                time=float(problem.time[i]),
                cost=float(problem.cost[i]),
                offset=offset,
            )
        )
    return tuple(members)


def selection_json(result: SelectionResult) -> dict[str, Any]:
    """What the store keeps of a selection (opaque JSON to the store)."""
    return {
        "chosen": result.chosen.to_json() if result.chosen else None,
        "assignments": [],
        "pareto": [c.to_json() for c in result.pareto],
        "optimizer": result.optimizer,
        "elapsed_ms": round(result.elapsed_ms, 3),
        "candidates": result.candidates,
        "complete": result.complete,
        "note": result.note,
    }
