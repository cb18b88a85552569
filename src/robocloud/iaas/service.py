"""The request life cycle of one cloud's IaaS (the thesis's Virtualization Engine at work).

A request's path (ARCHITECTURE.md): stored as ``received`` -> ``selecting``:
the robots in view, minus the reserved ones, go through the selection
pipeline -> each chosen robot is reserved in the store (the store refuses a
robot another request holds; selection then runs again without it) -> the
robots are sent their commands and acknowledge -> ``dispatched`` -> their
state messages move the request to ``underway`` and, once every robot is
done, ``completed``. A robot that fails on the way is replaced within what is
left of the request's cost and time, or the request fails with a reason.
Every state change is committed to the store before anyone is told.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import AsyncIterator, Callable, Coroutine, Sequence
from dataclasses import dataclass, field
from typing import Any

from robocloud.domain import Robot, Task, is_final
from robocloud.errors import Conflict, NotFound, RoboCloudError
from robocloud.federation.messages import CloudInfo
from robocloud.federation.view import FederationView
from robocloud.fleet.messages import Assign, State
from robocloud.iaas.config import Settings
from robocloud.selection.pipeline import select
from robocloud.selection.result import SelectionResult
from robocloud.storage import RequestRecord, RequestStore

log = logging.getLogger(__name__)


@dataclass
class Assigned:
    """One robot working for a request, as the IaaS tracks it."""

    robot: str
    cloud: str
    capabilities: list[str]
    time: float
    cost: float
    phase: str = "pending"
    progress: float = 0.0
    confirmed: bool = True  # False after a restart, until the robot reports this request
    watched_at: float = 0.0  # when this IaaS began to follow the robot (its clock)

    def to_json(self) -> dict[str, Any]:
        return {
            "robot": self.robot,
            "cloud": self.cloud,
            "capabilities": self.capabilities,
            "time": self.time,
            "cost": self.cost,
        }


@dataclass
class Tracking:
    """A dispatched request: its task, its robots, when it started."""

    request_id: str
    task: Task
    robots: dict[str, Assigned]
    dispatched_at: float  # wall clock, seconds
    selection: dict[str, Any] = field(default_factory=dict)
    recovered_at: float | None = None


def assignments_for(
    result: SelectionResult, robots: Sequence[Robot], task: Task, ids: Sequence[str]
) -> list[Assigned]:
    """The chosen robots with the capabilities each brings, its t_i and c_i."""
    from robocloud.selection.problem import robot_terms

    by_id = {robot.id: robot for robot in robots}
    chosen = [by_id[i] for i in ids]
    terms = robot_terms(chosen, task)
    return [
        Assigned(
            robot=robot.id,
            cloud=robot.cloud,
            capabilities=[name for k, name in enumerate(terms.capabilities) if terms.uses[i, k]],
            time=float(terms.time[i]),
            cost=float(terms.cost[i]),
        )
        for i, robot in enumerate(chosen)
    ]


class RequestService:
    """Runs every request of one cloud from ``received`` to a final state."""

    def __init__(
        self,
        settings: Settings,
        store: RequestStore,
        view: FederationView,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.settings = settings
        self.store = store
        self.view = view
        self.link = view.link
        self.clock = clock
        self._tracking: dict[str, Tracking] = {}
        self._robot_request: dict[str, str] = {}
        self._locks: dict[str, asyncio.Lock] = {}
        self._select_lock = asyncio.Lock()
        self._listeners: dict[str, set[asyncio.Queue[RequestRecord | None]]] = {}
        self._tasks: set[asyncio.Task[Any]] = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._started_at = 0.0
        # This cloud's presence summary (set by the app from its Home).
        self.home_info: Callable[[], CloudInfo] = lambda: CloudInfo(
            cloud=settings.cloud, robots=len(self.link.robots()), idle=0
        )

    # -- life of the service -------------------------------------------------

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._started_at = self.clock()
        self.view.on_state(self._state_from_thread)
        await self._recover()
        self._spawn(self._watch())

    async def stop(self) -> None:
        for task in list(self._tasks):
            task.cancel()
        for task in list(self._tasks):
            with contextlib.suppress(BaseException):
                await task
        for queues in self._listeners.values():
            for queue in queues:
                queue.put_nowait(None)

    def _spawn(self, coroutine: Coroutine[Any, Any, Any]) -> asyncio.Task[Any]:
        task: asyncio.Task[Any] = asyncio.ensure_future(coroutine)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return task

    def _lock(self, request_id: str) -> asyncio.Lock:
        return self._locks.setdefault(request_id, asyncio.Lock())

    # -- what the HTTP API calls ------------------------------------------------

    async def submit(
        self, application: str, task: Task, label: str | None, idempotency_key: str | None
    ) -> RequestRecord:
        record, created = await asyncio.to_thread(
            self.store.create_request,
            application,
            task.model_dump(mode="json"),
            label,
            idempotency_key,
        )
        if created:
            self._spawn(self._run(record.id))
        return record

    async def get(self, application: str, request_id: str) -> RequestRecord:
        if self.store.local_reads:
            # Measured (benchmarks/service.py, 1,000 robots, GET at 200/s):
            # the two thread hand-offs of to_thread, not the 0.5 ms read,
            # made the slow tail.
            record = self.store.get(request_id, application)
        else:
            record = await asyncio.to_thread(self.store.get, request_id, application)
        if record is None:
            raise NotFound(f"there is no request {request_id!r}.", request_id)
        return record

    async def cancel(self, application: str, request_id: str) -> RequestRecord:
        record = await self.get(application, request_id)
        async with self._lock(request_id):
            record = await self.get(application, request_id)
            if record.state == "canceled":
                return record
            if is_final(record.state):
                raise Conflict(
                    f"request {request_id} is already {record.state}; only a request that is "
                    "not finished can be canceled."
                )
            record = await asyncio.to_thread(
                self.store.transition, request_id, "canceled", None, "canceled by the application"
            )
            tracking = self._forget(request_id)
        self._publish(record)
        if tracking is not None:
            await self._stop_robots(request_id, list(tracking.robots.values()))
        return record

    def progress_of(self, robot_id: str) -> tuple[str, float] | None:
        request_id = self._robot_request.get(robot_id)
        tracking = self._tracking.get(request_id) if request_id else None
        if tracking is None or robot_id not in tracking.robots:
            return None
        assigned = tracking.robots[robot_id]
        return assigned.phase, assigned.progress

    def coalition_robots(self, request_id: str) -> list[str]:
        """The robots working for a request now (what the homes of remote robots ask)."""
        tracking = self._tracking.get(request_id)
        return sorted(tracking.robots) if tracking is not None else []

    def request_of(self, robot_id: str) -> str | None:
        return self._robot_request.get(robot_id)

    async def events(self, application: str, request_id: str) -> AsyncIterator[RequestRecord]:
        """The request now, then after each change, until it is final."""
        queue: asyncio.Queue[RequestRecord | None] = asyncio.Queue()
        self._listeners.setdefault(request_id, set()).add(queue)
        try:
            record = await self.get(application, request_id)
            yield record
            while not is_final(record.state):
                update = await queue.get()
                if update is None:
                    return
                record = update
                yield record
        finally:
            self._listeners.get(request_id, set()).discard(queue)

    def _publish(self, record: RequestRecord) -> None:
        for queue in self._listeners.get(record.id, ()):
            queue.put_nowait(record)

    # -- selection and dispatch ---------------------------------------------

    async def _remote(self, request_id: str, task: Task, exclude: set[str]) -> list[Robot]:
        """The other clouds' idle robots (gathered outside the selection lock)."""
        view = await asyncio.to_thread(self.view.remote_robots, task, exclude)
        for note in view.notes:
            await self._event(request_id, note)
        return view.robots

    def _local(self, exclude: set[str]) -> list[Robot]:
        """This cloud's robots, read under the selection lock so no one else holds them."""
        return [r for r in self.view.local_robots(self._robot_request) if r.id not in exclude]

    async def _run(self, request_id: str, resumed: bool = False) -> None:
        try:
            async with self._lock(request_id):
                record = await asyncio.to_thread(self.store.get, request_id)
                if record is None or is_final(record.state):
                    return
                if record.state == "received":
                    record = await asyncio.to_thread(self.store.transition, request_id, "selecting")
                    self._publish(record)
                await self._select_and_dispatch(record)
        except Conflict:
            # The request was canceled meanwhile; its reservations went with it.
            log.info("request %s moved on while it was being selected", request_id)
        except Exception as error:  # the request must not be left hanging
            log.exception("request %s failed", request_id)
            await self._fail(request_id, f"internal error while selecting: {error}")

    async def _select_and_dispatch(self, record: RequestRecord) -> None:
        request_id = record.id
        task = Task.model_validate(record.task)
        excluded: set[str] = set()
        for attempt in range(1, self.settings.reselect_attempts + 1):
            remote = await self._remote(request_id, task, excluded)
            async with self._select_lock:
                robots = [*self._local(excluded), *remote]
                result = await asyncio.to_thread(
                    select,
                    robots,
                    task,
                    self.settings.optimizer,  # type: ignore[arg-type]
                    seed=self.settings.seed,
                )
                if result.chosen is None:
                    record = await asyncio.to_thread(
                        self.store.transition,
                        request_id,
                        "rejected",
                        result.reason,
                        None,
                        selection_json(result, []),
                    )
                    self._publish(record)
                    return
                home = {robot.id: robot.cloud for robot in robots}
                pairs = [(robot, home[robot]) for robot in result.chosen.robots]
                taken = await asyncio.to_thread(self.view.reserve, request_id, pairs)
            if taken:
                excluded |= set(taken)
                await self._event(
                    request_id,
                    f"robots {', '.join(taken)} were taken by another "
                    f"request meanwhile; selecting again (attempt {attempt})",
                )
                continue
            assigned = assignments_for(result, robots, task, result.chosen.robots)
            refused = await self._assign(request_id, task, assigned)
            if refused:
                accepted = [a for a in assigned if a.robot not in refused]
                await self._stop_robots(request_id, accepted)
                await asyncio.to_thread(self.view.release, request_id, pairs, "refused")
                excluded |= set(refused)
                await self._event(
                    request_id,
                    "; ".join(
                        f"robot {robot} refused the task: {why}" for robot, why in refused.items()
                    )
                    + f"; selecting again (attempt {attempt})",
                )
                continue
            selection = selection_json(result, assigned)
            selection["dispatched_at"] = self.clock()
            try:
                record = await asyncio.to_thread(
                    self.store.transition,
                    request_id,
                    "dispatched",
                    None,
                    f"{len(assigned)} robot{'s' if len(assigned) != 1 else ''}: "
                    f"{', '.join(a.robot for a in assigned)}",
                    selection,
                )
            except Conflict:
                await self._stop_robots(request_id, assigned)
                await asyncio.to_thread(self.view.release, request_id, pairs, "canceled")
                raise
            lost = await asyncio.to_thread(self.view.confirm, request_id, pairs)
            if lost:
                await self._event(
                    request_id,
                    f"the leases on {', '.join(lost)} could not be "
                    "made firm; their homes may give them away",
                )
            self._track(
                Tracking(
                    request_id,
                    task,
                    {a.robot: a for a in assigned},
                    selection["dispatched_at"],
                    selection,
                )
            )
            self._publish(record)
            return
        await self._fail(
            request_id,
            f"no coalition could be reserved and dispatched in "
            f"{self.settings.reselect_attempts} attempts; robots kept being taken "
            "or refusing",
        )

    async def _assign(
        self, request_id: str, task: Task, assigned: Sequence[Assigned]
    ) -> dict[str, str]:
        """Send every robot its command; the robots that refused, with why."""
        commands = [
            Assign(
                request_id=request_id,
                location=list(task.location),
                capabilities=a.capabilities,
                execution=task.execution,
            )
            for a in assigned
        ]
        acks = await asyncio.gather(
            *(
                asyncio.to_thread(self.view.assign, a.robot, a.cloud, command)
                for a, command in zip(assigned, commands, strict=True)
            )
        )
        return {
            a.robot: ack.error or "no reason given"
            for a, ack in zip(assigned, acks, strict=True)
            if not ack.ok
        }

    async def _stop_robots(self, request_id: str, robots: Sequence[Assigned]) -> None:
        """Stop the robots; at other clouds this also releases them."""
        await asyncio.gather(
            *(asyncio.to_thread(self.view.cancel, a.robot, a.cloud, request_id) for a in robots)
        )

    async def _event(self, request_id: str, detail: str) -> None:
        record = await asyncio.to_thread(self.store.add_event, request_id, detail)
        self._publish(record)

    async def _fail(self, request_id: str, reason: str) -> None:
        tracking = self._forget(request_id)
        try:
            record = await asyncio.to_thread(self.store.transition, request_id, "failed", reason)
        except RoboCloudError:
            return  # already final
        self._publish(record)
        if tracking is not None:
            await self._stop_robots(request_id, list(tracking.robots.values()))

    # -- tracking dispatched requests -----------------------------------------

    def _track(self, tracking: Tracking) -> None:
        self._tracking[tracking.request_id] = tracking
        for robot, assigned in tracking.robots.items():
            self._robot_request[robot] = tracking.request_id
            assigned.watched_at = self.clock()
            self.view.watch(robot, assigned.cloud)

    def _forget(self, request_id: str) -> Tracking | None:
        tracking = self._tracking.pop(request_id, None)
        if tracking is not None:
            for robot, assigned in tracking.robots.items():
                if self._robot_request.get(robot) == request_id:
                    del self._robot_request[robot]
                self.view.unwatch(robot, assigned.cloud)
        return tracking

    def _state_from_thread(self, state: State) -> None:
        """Called on Zenoh's thread for every state message; hops to the loop."""
        if self._loop is not None and state.id in self._robot_request:
            self._loop.call_soon_threadsafe(self._on_state, state)

    def _on_state(self, state: State) -> None:
        request_id = self._robot_request.get(state.id)
        tracking = self._tracking.get(request_id) if request_id else None
        if tracking is None or request_id is None:
            return
        assigned = tracking.robots.get(state.id)
        if assigned is None:
            return
        mine = state.task is not None and state.task.request_id == request_id
        if mine and state.task is not None and assigned.phase != "done":
            assigned.confirmed = True
            phase = state.task.phase
            # A finished task lingers in the state while the robot goes on
            # with its life (it may go offline once done): only a robot that
            # has not finished can fail.
            if phase == "failed" or (state.status == "offline" and phase != "done"):
                self._spawn(
                    self._robot_failed(
                        request_id,
                        state.id,
                        "its battery died" if state.battery <= 0 else "it went offline",
                    )
                )
                return
            changed = phase != assigned.phase
            assigned.phase, assigned.progress = phase, state.task.progress
            if changed:
                self._spawn(self._advance(request_id))

    async def _advance(self, request_id: str) -> None:
        """Move a dispatched request on when its robots' phases say so."""
        async with self._lock(request_id):
            tracking = self._tracking.get(request_id)
            if tracking is None:
                return
            phases = [a.phase for a in tracking.robots.values()]
            record = await asyncio.to_thread(self.store.get, request_id)
            if record is None or is_final(record.state):
                return
            if all(phase == "done" for phase in phases):
                if record.state == "dispatched":
                    record = await asyncio.to_thread(self.store.transition, request_id, "underway")
                    self._publish(record)
                self._forget(request_id)
                record = await asyncio.to_thread(
                    self.store.transition,
                    request_id,
                    "completed",
                    None,
                    "every robot finished its part",
                )
                self._publish(record)
            elif record.state == "dispatched" and any(
                p in ("travel", "work", "done") for p in phases
            ):
                record = await asyncio.to_thread(
                    self.store.transition, request_id, "underway", None, "the robots are moving"
                )
                self._publish(record)
            else:
                self._publish(record)  # progress only

    async def _watch(self) -> None:
        """Once a second: robots gone silent, and robots lost across a restart."""
        while True:
            await asyncio.sleep(0.5)
            ages = self.view.ages()
            now = self.clock()
            for request_id, tracking in list(self._tracking.items()):
                for robot_id, assigned in list(tracking.robots.items()):
                    if assigned.phase == "done":
                        continue
                    # Silence counts from the later of its latest state and the
                    # moment this IaaS began to follow it: a remote robot's first
                    # state may still be on its way, and an old state kept from
                    # an earlier request says nothing about this one.
                    since = now - max(self._started_at, assigned.watched_at)
                    silent = min(ages.get(robot_id, since), since)
                    if silent > self.settings.offline_after:
                        self._spawn(
                            self._robot_failed(
                                request_id, robot_id, f"it has been silent for {silent:.0f} s"
                            )
                        )
                    elif (
                        not assigned.confirmed
                        and tracking.recovered_at is not None
                        and (now - tracking.recovered_at > self.settings.offline_after)
                    ):
                        self._spawn(
                            self._robot_failed(
                                request_id,
                                robot_id,
                                "it no longer reports this request after the restart",
                            )
                        )

    # -- failures and replacement ---------------------------------------------

    async def _robot_failed(self, request_id: str, robot_id: str, why: str) -> None:
        async with self._lock(request_id):
            tracking = self._tracking.get(request_id)
            if tracking is None or robot_id not in tracking.robots:
                return
            failed = tracking.robots.pop(robot_id)
            self._robot_request.pop(robot_id, None)
            self.view.unwatch(robot_id, failed.cloud)
            # At another cloud the release may not arrive (the cloud may be the
            # failure); it reconciles with this one when it is back.
            await asyncio.to_thread(
                self.view.release, request_id, [(robot_id, failed.cloud)], f"robot failed: {why}"
            )
            await self._event(request_id, f"robot {robot_id} failed: {why}")
            await self._replace(tracking, failed)

    async def _replace(self, tracking: Tracking, failed: Assigned) -> None:
        """Select robots for the capabilities the failed robot brought."""
        request_id, task = tracking.request_id, tracking.task
        remaining = list(tracking.robots.values())
        missing = {}
        for name, need in task.required.items():
            have = sum(name in a.capabilities for a in remaining)
            if have < need:
                missing[name] = need - have
        if not missing:
            await self._advance_locked_free(request_id)
            return
        elapsed = (self.clock() - tracking.dispatched_at) * self.settings.time_scale
        time_left = task.max_time - elapsed
        cost_left = task.max_cost - sum(a.cost for a in remaining)
        robots_left = task.max_robots - len(remaining)
        reason = None
        if time_left <= 0:
            reason = f"no time is left of max_time {task.max_time:g} s"
        elif cost_left < 0 or robots_left < 1:
            reason = "no cost or robot is left within the request's limits"
        if reason is None:
            sub = task.model_copy(
                update={
                    "sensing": {k: v for k, v in missing.items() if k in task.sensing},
                    "actuating": {k: v for k, v in missing.items() if k in task.actuating},
                    "max_robots": robots_left,
                    "max_cost": cost_left,
                    "max_time": time_left,
                }
            )
            exclude = set(tracking.robots) | {failed.robot}
            remote = await self._remote(request_id, sub, exclude)
            async with self._select_lock:
                robots = [*self._local(exclude), *remote]
                result = await asyncio.to_thread(
                    select,
                    robots,
                    sub,
                    self.settings.optimizer,  # type: ignore[arg-type]
                    seed=self.settings.seed,
                )
                if result.chosen is not None:
                    home = {robot.id: robot.cloud for robot in robots}
                    pairs = [(robot, home[robot]) for robot in result.chosen.robots]
                    taken = await asyncio.to_thread(self.view.reserve, request_id, pairs)
                    if taken:
                        result = None  # type: ignore[assignment]
                        reason = "the replacement robots were taken meanwhile"
                else:
                    reason = result.reason
            if result is not None and result.chosen is not None:
                new = assignments_for(result, robots, sub, result.chosen.robots)
                refused = await self._assign(request_id, sub, new)
                if not refused:
                    await asyncio.to_thread(self.view.confirm, request_id, pairs)
                    for a in new:
                        tracking.robots[a.robot] = a
                        self._robot_request[a.robot] = request_id
                        a.watched_at = self.clock()
                        self.view.watch(a.robot, a.cloud)
                    tracking.selection.setdefault("replacements", []).append(
                        {"failed": failed.robot, "by": [a.robot for a in new]}
                    )
                    tracking.selection["assignments"] = [
                        a.to_json() for a in tracking.robots.values()
                    ]
                    await asyncio.to_thread(
                        self.store.set_selection, request_id, tracking.selection
                    )
                    await self._event(
                        request_id,
                        f"robot {failed.robot} replaced by {', '.join(a.robot for a in new)}",
                    )
                    return
                await self._stop_robots(request_id, new)
                await asyncio.to_thread(self.view.release, request_id, pairs, "refused")
                reason = "; ".join(f"robot {r} refused: {w}" for r, w in refused.items())
        self._forget(request_id)
        try:
            record = await asyncio.to_thread(
                self.store.transition,
                request_id,
                "failed",
                f"robot {failed.robot} failed and no replacement was found: {reason}",
            )
        except Conflict:
            return
        self._publish(record)
        await self._stop_robots(request_id, remaining)

    async def _advance_locked_free(self, request_id: str) -> None:
        self._spawn(self._advance(request_id))

    # -- restart ------------------------------------------------------------

    async def _recover(self) -> None:
        """Resume what a previous run of this IaaS left unfinished."""
        for record in await asyncio.to_thread(self.store.active):
            if record.application.startswith("cloud:"):
                continue  # another cloud's request this cloud lends robots to (iaas.home)
            if record.state in ("received", "selecting"):
                await asyncio.to_thread(self.store.release, record.id, None)
                await self._event(record.id, "resumed after a restart of the IaaS")
                self._spawn(self._run(record.id, resumed=True))
                continue
            selection = record.selection or {}
            assigned = [Assigned(**a, confirmed=False) for a in selection.get("assignments", [])]
            if not assigned:
                await self._fail(record.id, "its coalition was lost in a restart of the IaaS")
                continue
            tracking = Tracking(
                record.id,
                Task.model_validate(record.task),
                {a.robot: a for a in assigned},
                float(selection.get("dispatched_at", self.clock())),
                selection,
                recovered_at=self.clock(),
            )
            self._track(tracking)
            await self._event(
                record.id, "resumed after a restart of the IaaS; waiting for its robots to report"
            )

    def loan_ended(self, request_id: str, robot: str, home: str, why: str) -> None:
        """A home ended the loan of ``robot`` on its own while this cloud was away.

        ``robocloud.iaas.home.OriginStatus``; called on a worker thread, maybe
        twice for one loan. The request's history says so, and a robot still
        in its coalition is treated as failed (replaced or the request fails).
        """
        loop = self._loop
        if loop is None:
            return

        async def ended() -> None:
            with contextlib.suppress(RoboCloudError):
                await self._event(request_id, f"{home} ended the loan of robot {robot}: {why}")
            tracking = self._tracking.get(request_id)
            if tracking is not None and robot in tracking.robots:
                await self._robot_failed(request_id, robot, f"{home} ended its loan: {why}")

        loop.call_soon_threadsafe(lambda: self._spawn(ended()))


def selection_json(result: SelectionResult, assigned: Sequence[Assigned]) -> dict[str, Any]:
    """What the store keeps of a selection (opaque JSON to the store)."""
    return {
        "chosen": result.chosen.to_json() if result.chosen else None,
        "assignments": [a.to_json() for a in assigned],
        "pareto": [c.to_json() for c in result.pareto],
        "optimizer": result.optimizer,
        "elapsed_ms": round(result.elapsed_ms, 3),
        "candidates": result.candidates,
    }
