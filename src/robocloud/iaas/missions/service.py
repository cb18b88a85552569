"""This IaaS's missions: their runners, what they reach, and what the HTTP API calls.

``MissionService`` starts one ``MissionRunner`` per mission, hands each
robot's report to the mission that holds it (``RobotRoutes`` routes the
robot to the mission's id), ticks the runners a few times a second, and
keeps every task it starts (awaited when it stops). The robots a mission
may take are those no request and no other mission holds: ``RobotRoutes``
(routes, claims, set-asides), the store's reservations and loans, and the
other clouds' idle robots, which their homes lend for the mission as a
whole (``FederationView.reserve`` with the mission's id).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import math
from collections.abc import AsyncIterator, Awaitable, Callable, Coroutine
from typing import Any, TypeVar

from robocloud.domain import Robot, is_final
from robocloud.domain.mission_ids import MISSION_ID, holder_of
from robocloud.errors import InvalidInput, NotFound, RoboCloudError
from robocloud.federation.reconcile import OriginStatus
from robocloud.federation.view import FederationView
from robocloud.fleet.messages import Ack, Assign, State
from robocloud.iaas.feed import Feed
from robocloud.iaas.lifecycle import Rules
from robocloud.iaas.missions.book import MissionBook, MissionRecord
from robocloud.iaas.missions.models import MissionCreate, MissionPublic, mission_json
from robocloud.iaas.missions.plans import quick_plan
from robocloud.iaas.missions.runner import MissionRunner, Ports, robot_of
from robocloud.iaas.owned import spawn_owned
from robocloud.iaas.routes import RobotRoutes
from robocloud.planning.mission import MAX_MISSION_ROBOTS, Mission, MissionInput, to_problem
from robocloud.planning.plan import Plan
from robocloud.planning.problem import Problem
from robocloud.storage import MissionRow, RequestStore

log = logging.getLogger(__name__)
T = TypeVar("T")
TICK = 0.2  # seconds between two ticks of the runners (watchdog, deferred assigns)


class MissionService:
    def __init__(
        self,
        cloud: str,
        book: MissionBook,
        store: RequestStore,
        view: FederationView,
        routes: RobotRoutes,
        rules: Rules,
        blocking: Callable[..., Awaitable[Any]],
        wall: Callable[[], float],
        plan: Callable[[Problem, float], Plan] | None = None,
    ) -> None:
        self.cloud = cloud
        self.book = book
        self.store = store
        self.view = view
        self.routes = routes
        self.rules = rules
        self.blocking = blocking
        self.wall = wall
        self._solve = plan
        self._planning = asyncio.Semaphore(1)
        self._saving = asyncio.Lock()
        self.feed: Feed[MissionPublic] = Feed()
        self._dirty: dict[str, MissionRecord] = {}  # missions changed since last stored
        self._stored: dict[str, tuple[str, int, int]] = {}  # id -> (state, history, version)
        self._runners: dict[str, MissionRunner] = {}
        self._tasks: set[asyncio.Task[Any]] = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop_listening: Callable[[], None] = lambda: None
        self.ports = Ports(
            cloud=cloud,
            rules=rules,
            wall=wall,
            gather=self._gather,
            plan=self._plan,
            quick=quick_plan,
            hold=self._hold,
            release=self._release,
            route=self._route,
            assign=self._assign,
            start=self._start_work,
            stop=self._stop,
            state_of=self._state_of,
            publish=self._publish,
        )

    # -- life of the service -------------------------------------------------------

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        await self._end_unfinished()
        self._stop_listening = self.view.on_state(self._state_from_thread)
        self._spawn(self._tick_forever(), "the missions' ticks")

    async def stop(self) -> None:
        self._stop_listening()
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        with contextlib.suppress(RoboCloudError):
            await self._save_dirty()
        self.feed.close()

    async def _end_unfinished(self) -> None:
        """Missions a previous run left unfinished end failed: they are not resumed."""
        for row in await self.blocking(self.store.unfinished_missions):
            now = self.wall()
            why = (
                f"the IaaS restarted while the mission was {row.state}; missions are not "
                "resumed (robots still at its tasks are told to stop)"
            )
            document = {
                **row.document,
                "state": "failed",
                "reason": why,
                "updated_at": now,
                "history": [*row.document.get("history", []),
                            {"at": now, "state": "failed", "note": why}],
            }
            await self.blocking(
                self.store.save_mission, dataclasses.replace(row, state="failed", document=document)
            )
            log.warning("mission %s ended: %s", row.id, why)

    def _publish(self, record: MissionRecord) -> None:
        self.feed.publish(mission_json(record))
        version = (record.plan or {}).get("version", 0)
        if self._stored.get(record.id) != (record.state, len(record.history), version):
            self._dirty[record.id] = record

    async def _save_dirty(self) -> None:
        """Store the missions that changed, one after the other (in order, no overtaking)."""
        async with self._saving:
            while self._dirty:
                mission_id, record = next(iter(self._dirty.items()))
                del self._dirty[mission_id]
                version = (record.plan or {}).get("version", 0)
                self._stored[mission_id] = (record.state, len(record.history), version)
                await self.blocking(self.store.save_mission, row_of(record))
                if is_final(record.state):
                    self._stored.pop(mission_id, None)

    def _spawn(self, work: Coroutine[Any, Any, Any], what: str) -> asyncio.Task[Any]:
        """A task this service owns: awaited in ``stop``, its error logged."""
        return spawn_owned(self._tasks, work, what, log)

    async def _tick_forever(self) -> None:
        while True:
            await asyncio.sleep(TICK)
            try:
                await self._save_dirty()
            except RoboCloudError as error:
                log.warning("the missions could not be stored now: %s", error)
            for runner in list(self._runners.values()):
                try:
                    await runner.tick()
                except Exception:
                    log.exception("the tick of mission %s failed", runner.id)
                if is_final(runner.record.state):
                    self._runners.pop(runner.id, None)

    # -- what the HTTP API calls ------------------------------------------------------

    async def submit(
        self, application: str, body: MissionCreate, idempotency_key: str | None
    ) -> MissionPublic:
        mission = body.mission()
        to_problem(MissionInput(robots=[], mission=mission))  # its ids and precedence: a 422
        posted = body.model_dump(mode="json")
        if idempotency_key is not None:
            stored = await self.blocking(self.store.mission_by_key, application, idempotency_key)
            if stored is not None and stored.id not in self._runners:
                return _same_body(stored.document, posted, idempotency_key)
        record, created = self.book.create(
            application, mission, posted, body.label, body.time_limit, idempotency_key,
            self.wall(),
        )
        if not created:
            return _same_body(mission_json(record).model_dump(mode="json") | {"body": record.body},
                              posted, idempotency_key)
        await self.blocking(self.store.save_mission, row_of(record))
        runner = MissionRunner(record, self.ports)
        self._runners[record.id] = runner
        self._spawn(self._run(runner), f"mission {record.id}")
        return mission_json(record)

    async def _run(self, runner: MissionRunner) -> None:
        try:
            await runner.begin()
        except Exception as error:
            log.exception("mission %s could not begin", runner.id)
            with contextlib.suppress(Exception):
                await runner.fail_inside(f"internal error: {error}")
        if is_final(runner.record.state):
            self._runners.pop(runner.id, None)

    async def get(self, application: str, mission_id: str) -> MissionPublic:
        if MISSION_ID.fullmatch(mission_id):
            record = self.book.get(mission_id, application)
            if record is not None:
                return mission_json(record)
            stored = await self.blocking(self.store.mission, mission_id, application)
            if stored is not None:
                return public_of(stored.document)
        raise NotFound(f"there is no mission {mission_id!r}.", mission_id)

    async def page(
        self, application: str, state: str | None, limit: int, before: str | None
    ) -> tuple[list[MissionPublic], str | None]:
        await self._save_dirty()  # the list is the store's: what changed is in it first
        rows, cursor = await self.blocking(self.store.missions, application, state, limit, before)
        shown = []
        for row in rows:
            live = self.book.get(row.id, application)
            shown.append(mission_json(live) if live is not None else public_of(row.document))
        return shown, cursor

    async def cancel(self, application: str, mission_id: str) -> MissionPublic:
        await self.get(application, mission_id)
        runner = self._runners.get(mission_id)
        if runner is not None:
            await runner.cancel()
        return await self.get(application, mission_id)

    def events(
        self,
        application: str,
        mission_id: str,
        updates: asyncio.Queue[MissionPublic | None],
    ) -> AsyncIterator[MissionPublic]:
        """The mission now, then each change (``updates``: ``feed.subscribe``), until final."""
        return self.feed.follow(updates, lambda: self.get(application, mission_id))

    def loan_ended(self, mission_id: str, robot: str, home: str, why: str) -> None:
        """A robot's home ended its loan to one of our missions on its own (any thread)."""
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self._loan_ended, mission_id, robot, home, why)

    def _loan_ended(self, mission_id: str, robot: str, home: str, why: str) -> None:
        runner = self._runners.get(mission_id)
        if runner is not None:
            self._spawn(
                runner.lost(robot, f"its home {home} ended the loan: {why}"),
                f"the loan of {robot} to mission {mission_id}",
            )

    # -- robots' reports ------------------------------------------------------------

    def _state_from_thread(self, state: State) -> None:
        """On Zenoh's threads: a state of a robot a mission holds goes to the loop."""
        loop = self._loop
        held_by = self.routes.request_of(state.id)
        if loop is not None and held_by is not None and MISSION_ID.fullmatch(held_by):
            loop.call_soon_threadsafe(self._on_state, held_by, state)

    def _on_state(self, mission_id: str, state: State) -> None:
        runner = self._runners.get(mission_id)
        if runner is not None:
            self._spawn(runner.report(state), f"a report to mission {mission_id}")

    def _state_of(self, robot_id: str) -> State | None:
        state = self.view.link.state(robot_id)
        if state is None and self.view.overlay is not None:
            state = self.view.overlay.states().get(robot_id)
        return state

    # -- the ports ------------------------------------------------------------------

    async def _gather(self, mission: Mission, exclude: set[str]) -> list[Robot]:
        """The federation's robots a mission may take now (idle, not held), nearest first."""
        held = self.routes.held() | set(await self.blocking(self.store.reservations)) | exclude
        local = [r for r in self.view.local_robots(held) if r.status == "idle"]
        names = tuple(sorted({c for task in mission.tasks for c in task.required}))
        view = await self.blocking(self.view.idle_elsewhere, (mission.min_battery, names), held)
        remote = [robot_of(r) for r in view.robots]
        robots = [r for r in [*local, *remote] if r.id not in held]
        if len(robots) > MAX_MISSION_ROBOTS:
            x = sum(t.location[0] for t in mission.tasks) / len(mission.tasks)
            y = sum(t.location[1] for t in mission.tasks) / len(mission.tasks)
            robots.sort(key=lambda r: math.dist(r.position, (x, y)))
            robots = robots[:MAX_MISSION_ROBOTS]
        return robots

    async def _plan(self, problem: Problem, time_limit: float) -> Plan:
        """A plan within ``time_limit``, one mission at a time (each planner is a child
        process that uses both cores: side by side they would only share them)."""
        async with self._planning:
            if self._solve is not None:
                return await asyncio.to_thread(self._solve, problem, time_limit)
            from robocloud.planning.solve import solve

            return await asyncio.to_thread(solve, problem, time_limit)

    async def _hold(self, mission_id: str, robots: list[tuple[str, str]]) -> list[str]:
        """Hold robots for the mission: this cloud's in ``RobotRoutes``, the others lent."""
        local = [r for r, cloud in robots if cloud == self.cloud]
        taken = self.routes.take(mission_id, local)
        if taken:
            return taken
        in_store = set(await self.blocking(self.store.reservations))
        taken = [r for r in local if r in in_store]  # lent to another cloud just now
        remote = [(r, c) for r, c in robots if c != self.cloud]
        lent: list[tuple[str, str]] = []
        for pair in [] if taken else remote:
            # One by one: a home refuses a whole reservation for one robot that
            # went busy meanwhile, without saying which (a mission's robots are
            # many, and the plan took seconds).
            refused = await self.blocking(self.view.reserve, mission_id, [pair])
            if refused:
                taken += refused
            else:
                lent.append(pair)
        if taken:
            for robot in local:
                self.routes.unfollow(mission_id, robot)
            if lent:
                await self.blocking(self.view.release, mission_id, lent, "the plan changed")
            return taken
        for robot, cloud in remote:
            self.routes.follow(mission_id, robot)
            self.view.watch(robot, cloud)
        return []

    def _route(self, mission_id: str, robot: str, task: str) -> None:
        self.routes.follow(mission_id, robot, task)

    async def _release(self, mission_id: str, robot: str, cloud: str, why: str) -> None:
        self.routes.unfollow(mission_id, robot)
        if cloud != self.cloud:
            self.view.unwatch(robot, cloud)
            with contextlib.suppress(RoboCloudError):
                await self.blocking(self.view.release, mission_id, [(robot, cloud)], why)

    async def _assign(self, robot: str, cloud: str, command: Assign) -> Ack:
        ack: Ack = await self.blocking(self.view.assign, robot, cloud, command)
        if ack.ok and cloud != self.cloud:
            # The loan turns firm once its first task is dispatched: kept while it works.
            with contextlib.suppress(RoboCloudError):
                await self.blocking(
                    self.view.confirm, holder_of(command.request_id), [(robot, cloud)]
                )
        return ack

    async def _start_work(self, robot: str, cloud: str, request_id: str) -> Ack:
        ack: Ack = await self.blocking(self.view.start, robot, cloud, request_id)
        return ack

    async def _stop(self, mission_id: str, robot: str, cloud: str, request_id: str) -> None:
        with contextlib.suppress(RoboCloudError):
            if cloud == self.cloud:
                await self.blocking(self.view.link.cancel, robot, request_id)
            else:  # at the home: the loan is the mission's, the robot told its task's end
                await self.blocking(self.view.cancel, robot, cloud, mission_id)


class Origins:
    """Who learns that a home ended a loan while this cloud was away: the mission the
    robot was lent for, or the request (``robocloud.federation.reconcile.OriginStatus``)."""

    def __init__(self, requests: OriginStatus, missions: MissionService) -> None:
        self.requests = requests
        self.missions = missions

    def loan_ended(self, request_id: str, robot: str, home: str, why: str) -> None:
        to = self.missions if MISSION_ID.fullmatch(request_id) else self.requests
        to.loan_ended(request_id, robot, home, why)


def row_of(record: MissionRecord) -> MissionRow:
    """What the store keeps of a mission: its JSON, and what was posted (for a retry)."""
    return MissionRow(
        id=record.id,
        application=record.application,
        idempotency_key=record.idempotency_key,
        state=record.state,
        created_at=record.created_at,
        document={**mission_json(record).model_dump(mode="json"), "body": record.body},
    )


def public_of(document: dict[str, Any]) -> MissionPublic:
    return MissionPublic.model_validate({k: v for k, v in document.items() if k != "body"})


def _same_body(document: dict[str, Any], posted: dict[str, Any], key: str | None) -> MissionPublic:
    """The mission an Idempotency-Key was used for, if the body is the same; else a 422."""
    if document.get("body") != posted:
        raise InvalidInput(
            f"Idempotency-Key {key!r} was already used for another mission "
            f"({document.get('id')}) with a different body; a new mission needs a new key.",
            "Idempotency-Key",
        )
    return public_of(document)
