"""A mission carried out over in-memory parts: the runner's rules, fast and without processes.

The robots are ``MemoryRobotLink``'s (they answer commands by the robot
protocol's rules and move when stepped), the store is the memory store, the
clock is the test's, and the plans are the construction's (the planner's
first step, in this process: CP-SAT runs in a child and is the system
tests' and ``tests/planning``'s).
"""

from __future__ import annotations

import asyncio
from typing import Any

import pytest

from robocloud.domain import Robot
from robocloud.federation.view import FederationView
from robocloud.fleet import MemoryRobotLink
from robocloud.fleet.messages import Assign, Cancel, Start, State
from robocloud.iaas.lifecycle import Rules
from robocloud.iaas.missions.book import MissionBook, MissionRecord
from robocloud.iaas.missions.models import mission_json, read_body
from robocloud.iaas.missions.runner import MissionRunner
from robocloud.iaas.missions.service import MissionService
from robocloud.iaas.routes import RobotRoutes
from robocloud.planning.construction import best_construction
from robocloud.planning.plan import Plan
from robocloud.planning.problem import Problem
from robocloud.storage import MemoryRequestStore


class Clock:
    def __init__(self) -> None:
        self.now = 1_000_000.0

    def __call__(self) -> float:
        return self.now


def construction(problem: Problem, time_limit: float) -> Plan:
    schedule = best_construction(problem)
    return Plan(schedule, None, False, "anytime", 0.0, None if schedule else "no plan")


def state(i: int, x: float, protocol: str | None = "1.2", work: float = 10.0) -> State:
    robot = Robot.model_validate({
        "id": f"a-{i:04d}", "cloud": "cloud-a", "position": [x, 0.0], "speed": 1.0,
        "battery": 90.0, "status": "idle", "travel_cost_per_m": 0.1,
        "capabilities": {"grabber": {"kind": "actuating", "time": work, "cost": 1.0}},
    })
    return State.model_validate({
        **robot.model_dump(), "kind": "tribot", "task": None, "seq": 0, "sent_at": 0.0,
        "protocol": protocol,
    })


class World:
    """The parts of one cloud a mission reaches, in memory, with the test's clock."""

    def __init__(
        self,
        robots: list[State],
        offline_after: float = 30.0,
        planning: float = 0.0,
        stall_after: float = 30.0,
    ) -> None:
        self.clock = Clock()

        def plan(problem: Problem, time_limit: float) -> Plan:
            self.clock.now += planning  # the planner's wall time
            return construction(problem, time_limit)

        self._seen: dict[str, int] = {}
        self.link = MemoryRobotLink("cloud-a", robots, offline_after=1e9)
        self.routes = RobotRoutes(wall=self.clock)
        store = MemoryRequestStore()
        view = FederationView("cloud-a", store, self.link)

        async def blocking(function: Any, *args: Any) -> Any:
            return function(*args)

        self.service = MissionService(
            "cloud-a", MissionBook(store), store, view, self.routes,
            Rules(offline_after=offline_after, overrun_min=5.0, stall_after=stall_after),
            blocking, self.clock,
            plan=plan,
        )

    async def begin(self, body: dict[str, Any]) -> MissionRunner:
        mission = read_body(body)
        record, _ = self.service.book.create(
            "app", mission.mission(), body, None, 1.0, None, self.clock()
        )
        runner = MissionRunner(record, self.service.ports)
        await runner.begin()
        return runner

    async def run(self, runner: MissionRunner, seconds: float, dt: float = 1.0) -> None:
        """``seconds`` of robot time (and of the clock), each robot's state to the mission."""
        for _ in range(round(seconds / dt)):
            self.clock.now += dt
            self.link.step(dt)
            for robot_state in self.link.states().values():
                new = self._seen.get(robot_state.id) != robot_state.seq
                self._seen[robot_state.id] = robot_state.seq
                if new and robot_state.id in runner.record.robots:
                    await runner.report(robot_state)  # as the link calls its listeners
            await runner.tick()

    def sent(self, kind: type) -> list[tuple[str, Any]]:
        return [(robot, c) for robot, c in self.link.commands if isinstance(c, kind)]


TWO_FIRES = {
    "tasks": [
        {"id": "f1", "location": [0, 10], "actuating": {"grabber": 2}},
        {"id": "f2", "location": [30, 10], "actuating": {"grabber": 1}},
    ],
    "precedence": [["f1", "f2"]],
}


def json_of(record: MissionRecord) -> dict[str, Any]:
    return mission_json(record).model_dump(mode="json")


def test_tasks_start_together_in_plan_order_and_robots_are_released() -> None:
    async def scenario() -> None:
        world = World([state(0, 10.0), state(1, 40.0), state(2, 60.0)])
        runner = await world.begin(TWO_FIRES)
        record = runner.record
        assert record.state == "underway", record.history
        assigns = world.sent(Assign)
        assert assigns and all(c.hold for _, c in assigns)
        assert {c.request_id for _, c in assigns} <= {f"{record.id}.1", f"{record.id}.2"}
        f1, f2 = record.tasks[1], record.tasks[2]
        while f1.state != "work":
            assert not world.sent(Start)  # nobody starts before the last member is there
            await world.run(runner, 1.0)
        starts = world.sent(Start)
        assert {robot for robot, _ in starts} == set(f1.robots)
        assert all(world.routes.request_of(r) == record.id for r in record.robots)
        while f2.state != "work" and record.state == "underway":
            assert f2.state in ("pending", "travel", "waiting")
            await world.run(runner, 1.0)
        assert f1.state == "done"  # f2 began only after f1 ended
        await world.run(runner, 60.0)
        assert record.state == "completed", record.history
        shown = json_of(record)
        assert shown["progress"] == 1.0
        assert all(r["state"] == "released" for r in shown["plan"]["robots"])
        assert world.routes.kept_by_missions() == set()

    asyncio.run(scenario())


def test_a_robot_that_fails_is_replanned_around() -> None:
    async def scenario() -> None:
        world = World([state(0, 10.0), state(1, 40.0), state(2, 60.0), state(3, 80.0)])
        runner = await world.begin(TWO_FIRES)
        record = runner.record
        await world.run(runner, 2.0)
        victim = record.tasks[1].robots[0]
        world.link.fail(victim)
        await world.run(runner, 1.0)
        notes = [h["note"] for h in record.history]
        assert any(f"robot {victim} failed" in n for n in notes), notes
        assert any("re-planned (version 2" in n for n in notes), notes
        assert victim not in record.tasks[1].robots
        assert world.routes.request_of(victim) is None
        await world.run(runner, 200.0)
        assert record.state == "completed", record.history
        assert record.robots[victim].state == "failed"

    asyncio.run(scenario())


def test_a_robot_that_fails_at_work_leaves_its_task_to_be_done_again() -> None:
    async def scenario() -> None:
        world = World([state(0, 10.0), state(1, 40.0), state(2, 60.0), state(3, 80.0)])
        runner = await world.begin(TWO_FIRES)
        record = runner.record
        f1 = record.tasks[1]
        while f1.state != "work":
            await world.run(runner, 1.0)
        victim, partner = f1.robots
        world.link.fail(victim)
        await world.run(runner, 1.0)
        notes = [h["note"] for h in record.history]
        assert any(f"task f1 is planned again: {victim} left it unfinished" in n for n in notes)
        assert not any("task f1 done" in n for n in notes), notes  # not done without its part
        assert f1.state in ("pending", "travel", "waiting") and victim not in f1.robots
        stops = [c.request_id for robot, c in world.sent(Cancel) if robot == partner]
        assert f"{record.id}.1" in stops  # the partner stopped: the task begins again whole
        await world.run(runner, 300.0)
        assert record.state == "completed", record.history
        assert f1.state == "done" and len(f1.robots) == 2 and victim not in f1.done_by

    asyncio.run(scenario())


def test_a_silent_robot_fails_by_the_watchdog() -> None:
    async def scenario() -> None:
        world = World([state(0, 10.0), state(1, 40.0), state(2, 60.0)], offline_after=5.0)
        runner = await world.begin(TWO_FIRES)
        victim = runner.record.tasks[1].robots[0]
        world.link.silence(victim)
        await world.run(runner, 8.0)
        notes = [h["note"] for h in runner.record.history]
        assert any(f"robot {victim} failed: it has been silent" in n for n in notes), notes
        # Two robots are left for a task that needs two: it is re-planned on them.
        assert runner.record.state in ("underway", "completed"), notes

    asyncio.run(scenario())


def test_a_robot_stuck_on_its_way_fails_by_the_stall_rule() -> None:
    """lifecycle.Rules.failure, the requests' rule: a robot that goes on reporting but
    makes no progress for stall_after has failed, long before it is past its arrival."""

    async def scenario() -> None:
        world = World([state(0, 10.0), state(1, -10.0), state(2, 30.0)], stall_after=3.0)
        body = {**TWO_FIRES, "tasks": [
            {"id": "f1", "location": [0, 60], "actuating": {"grabber": 2}},
            {"id": "f2", "location": [30, 10], "actuating": {"grabber": 1}},
        ]}  # fmt: skip
        runner = await world.begin(body)
        record = runner.record
        f1 = next(run for run in record.tasks.values() if run.id == "f1")
        stuck = sorted(f1.robots)[0]
        await world.run(runner, 2.0)
        world.link.stick(stuck)
        await world.run(runner, 6.0)  # 60 m away at 1 m/s: its arrival is due in a minute
        member = record.robots[stuck]
        assert member.state == "failed", record.history
        notes = [h["note"] for h in record.history if stuck in h["note"]]
        assert any("reported no progress for 4 s (stalled)" in n for n in notes), notes

    asyncio.run(scenario())


def test_cancel_stops_every_robot_and_releases_it() -> None:
    async def scenario() -> None:
        world = World([state(0, 10.0), state(1, 40.0), state(2, 60.0)])
        runner = await world.begin(TWO_FIRES)
        await world.run(runner, 3.0)
        working = {
            s.id for s in world.link.states().values() if s.task and s.task.phase != "done"
        }
        assert working
        await runner.cancel()
        assert runner.record.state == "canceled"
        assert working <= {robot for robot, _ in world.sent(Cancel)}
        assert all(s.task is None for s in world.link.states().values() if s.id in working)
        assert world.routes.kept_by_missions() == set()
        await runner.cancel()  # again: harmless
        assert runner.record.state == "canceled"

    asyncio.run(scenario())


def test_a_robot_of_protocol_1_1_is_sent_late_and_never_held() -> None:
    async def scenario() -> None:
        # The old robot is near f2, which starts only after f1: it must not leave early.
        world = World([state(0, 10.0), state(1, -10.0), state(2, 30.0, protocol=None)])
        body = {**TWO_FIRES, "tasks": [
            {"id": "f1", "location": [0, 10], "actuating": {"grabber": 2}},
            {"id": "f2", "location": [30, 10], "actuating": {"grabber": 1}},
        ]}
        runner = await world.begin(body)
        old = runner.record.robots.get("a-0002")
        if old is None:
            pytest.skip("the plan did not use the old robot")
        assert not old.holds
        assert old.state == "assigned" and not [r for r, _ in world.sent(Assign) if r == old.id]
        await world.run(runner, 120.0)
        sent = [c for r, c in world.sent(Assign) if r == old.id]
        assert sent and not any(c.hold for c in sent)
        assert not [r for r, _ in world.sent(Start) if r == old.id]
        assert runner.record.state == "completed", runner.record.history

    asyncio.run(scenario())


def test_a_plans_time_0_is_when_it_was_made_not_when_planning_began() -> None:
    """A plan that took 30 s to make starts then: its 1.1 robot is not sent 30 s late, and
    the plan's times (the page's Gantt chart) are not 30 s ahead of the robots."""

    async def scenario() -> None:
        world = World([state(0, 10.0), state(1, -10.0), state(2, 30.0, protocol=None)],
                      planning=30.0)  # fmt: skip
        began = world.clock()
        runner = await world.begin(TWO_FIRES)
        record = runner.record
        assert record.started_at == began + 30.0, record.started_at - began
        f1 = next(run for run in record.tasks.values() if run.id == "f1")
        assert f1.start > 0.0  # its members still have to drive there
        # Protocol 1.2 robots get their assign (with hold) at once, not before their plan.
        assert {r for r, c in world.sent(Assign) if c.hold} == set(f1.robots) - {"a-0002"}

    asyncio.run(scenario())


def test_a_task_with_a_duration_keeps_its_members_that_long() -> None:
    """docs/model.md: members stay until start + duration, even when their capabilities'
    work (10 s of grabber here) is done sooner; then they go on to the next task."""

    async def scenario() -> None:
        world = World([state(0, 10.0), state(1, -10.0), state(2, 30.0)])
        body = {**TWO_FIRES, "tasks": [
            {"id": "f1", "location": [0, 10], "actuating": {"grabber": 2}, "duration": 60.0},
            {"id": "f2", "location": [30, 10], "actuating": {"grabber": 1}},
        ]}  # fmt: skip
        runner = await world.begin(body)
        record = runner.record
        f1 = next(run for run in record.tasks.values() if run.id == "f1")
        f2 = next(run for run in record.tasks.values() if run.id == "f2")
        await world.run(runner, f1.start + 30.0)  # there, 10 s of work done, 20 s more
        assert f1.state == "work" and f1.done_by == set(f1.robots), (f1.state, f1.done_by)
        # Nobody of f1 has been sent on: f2's assigns wait for f1's end.
        assert not [r for r, c in world.sent(Assign) if r in f1.robots and f2.wire(record.id)
                    == c.request_id]  # fmt: skip
        await world.run(runner, 40.0)  # past f1's 60 s
        assert f1.state == "done", record.history
        await world.run(runner, 120.0)
        assert record.state == "completed", record.history
        assert f2.start >= f1.start + 60.0 - 1e-6  # the plan had them stay, and they did

    asyncio.run(scenario())


def test_a_member_that_stayed_goes_on_when_a_slower_one_ends_the_task() -> None:
    """f1 lasts 20 s: one member's work takes 10 s (it stays), the other's 25 s (within the
    watchdog's tolerance of 10 s). f1 ends with the slow one's done, and the member that
    stayed goes on then too: to f2, or released. It is not left on f1."""

    async def scenario() -> None:
        world = World([state(0, 10.0), state(1, -10.0, work=25.0)])
        body = {**TWO_FIRES, "tasks": [
            {"id": "f1", "location": [0, 10], "actuating": {"grabber": 2}, "duration": 20.0},
            {"id": "f2", "location": [30, 10], "actuating": {"grabber": 1}},
        ]}  # fmt: skip
        runner = await world.begin(body)
        record = runner.record
        f1 = next(run for run in record.tasks.values() if run.id == "f1")
        for _ in range(200):
            await world.run(runner, 1.0)
            if f1.state == "done":
                break
        assert f1.state == "done", record.history
        left_on_f1 = [
            m.id for m in record.robots.values()
            if m.current is not None and m.current.task == f1.number and m.state == "working"
        ]  # fmt: skip
        assert left_on_f1 == [], record.history
        await world.run(runner, 120.0)
        assert record.state == "completed", record.history

    asyncio.run(scenario())


def test_robots_another_holds_are_not_taken() -> None:
    async def scenario() -> None:
        world = World([state(0, 10.0), state(1, 40.0), state(2, 60.0)])
        world.routes.claim("req-aaaaaaaaaaaa", ["a-0000", "a-0001"])
        runner = await world.begin(TWO_FIRES)
        assert runner.record.state == "rejected", runner.record.history
        assert world.routes.take("mis-bbbbbbbbbbbb", ["a-0000"]) == ["a-0000"]

    asyncio.run(scenario())


def test_bad_missions_are_refused_with_a_sentence() -> None:
    from robocloud.errors import InvalidInput

    with pytest.raises(InvalidInput, match="time_limit"):
        read_body({**TWO_FIRES, "time_limit": 100})
    with pytest.raises(InvalidInput, match="tasks"):
        read_body({"tasks": []})
    with pytest.raises(InvalidInput, match="body"):
        read_body([1, 2])


def test_a_restarted_iaas_ends_the_missions_it_left_unfinished() -> None:
    async def scenario() -> None:
        world = World([state(0, 10.0), state(1, 40.0), state(2, 60.0)])
        service = world.service
        runner = await world.begin(TWO_FIRES)
        service._publish(runner.record)
        await service._save_dirty()  # what the ticks do
        stored = service.store.mission(runner.id)
        assert stored is not None and stored.state == "underway"
        # Another process on the same store starts: the mission is not resumed.
        again = World([])
        again.service.store = service.store
        again.service.book.store = service.store
        await again.service.start()
        try:
            shown = await again.service.get("app", runner.id)
            assert shown.state == "failed" and "restarted" in (shown.reason or "")
            assert again.service.book.status(runner.id) == (True, True)
            listed, _ = await again.service.page("app", None, 10, None)
            assert [m.id for m in listed] == [runner.id]
        finally:
            await again.service.stop()

    asyncio.run(scenario())
