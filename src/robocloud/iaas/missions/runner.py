"""One mission carried out: its plan, its robots' commands, its watchdog, its re-plans.

``MissionRunner`` follows the plan in order. Each robot of the mission gets
its next task's assign when it has finished the previous one (``<mission
id>.<n>``, robocloud.domain.mission_ids); a robot of protocol 1.2 gets it at
once with ``hold`` and waits at the place; a task's work starts (the
``start`` command) when every member is there and its predecessors are done.
A robot of protocol 1.0 or 1.1 cannot wait on command: its assign is sent
late enough that it arrives at the task's planned start, and it works on
arrival (docs/protocol.md, "Missions").

A re-plan takes the planner's construction, in this process (milliseconds:
the robots wait for it, and every second they wait idle their owners may take
them); the first plan takes the whole planner within the mission's
``time_limit``.

The watchdog is the requests' rule (``robocloud.iaas.lifecycle.Rules``): a
robot silent for ``offline_after``, or past its expected arrival (while it
travels) or finish (while it works) plus the tolerance, or that reports its
task failed or itself offline, has failed. Its current task is stopped for it
and it is released; the tasks not yet started are then planned again from
where the robots are now (the failed one left out), and so is a task whose
work it left unfinished (whole: its other members are stopped and may be
chosen again). Tasks underway without it stay.
History says why. Robots are held for the mission as a whole (routed to the
mission's id in ``RobotRoutes``, lent for it by their homes) and each is
released as its last task ends, or at the end of the mission.

Every method runs on the event loop, one at a time (``_turn``); commands
to robots go through the ``Ports`` (threads).

Why one long file: planning, sending, starting, the watchdog and re-planning
all change the same tasks and robots of one mission under one turn; the
pure parts (a plan's legs, the re-plan's input) are in ``plans.py``.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from robocloud.domain import Robot, is_final
from robocloud.errors import InvalidInput
from robocloud.fleet.messages import Ack, Assign, State
from robocloud.iaas.lifecycle import Rules
from robocloud.iaas.missions.book import MissionRecord
from robocloud.iaas.missions.plans import (
    NOT_STARTED,
    OVER,
    RobotRun,
    TaskRun,
    adopt,
    plan_summary,
    problem_for,
    replan_input,
    travel_seconds,
)
from robocloud.planning.mission import Mission
from robocloud.planning.plan import Plan
from robocloud.planning.problem import Problem

log = logging.getLogger(__name__)

ATTEMPTS = 8  # plans per (re)planning when chosen robots are taken meanwhile
PROTOCOL_WAIT = 2.0  # wall seconds to hear a borrowed robot's protocol before its first assign
# A member's state while its task is in a phase (``RobotRun.state``).
MEMBER_STATE = {"travel": "travel", "waiting": "waiting", "work": "working"}


@dataclass(frozen=True)
class Ports:
    """What a runner reaches outside itself (``robocloud.iaas.missions.service`` builds it)."""

    cloud: str
    rules: Rules
    wall: Callable[[], float]
    # The federation's free robots for a mission (minus ``exclude``), and a plan.
    gather: Callable[[Mission, set[str]], Awaitable[list[Robot]]]
    plan: Callable[[Problem, float], Awaitable[Plan]]
    quick: Callable[[Problem], Plan]  # a re-plan's: robots wait for it
    # Hold robots (robot, cloud) for the mission: [] or those taken meanwhile.
    hold: Callable[[str, list[tuple[str, str]]], Awaitable[list[str]]]
    release: Callable[[str, str, str, str], Awaitable[None]]  # mission, robot, cloud, why
    route: Callable[[str, str, str], None]  # mission, robot, task request id
    assign: Callable[[str, str, Assign], Awaitable[Ack]]  # robot, cloud, command
    start: Callable[[str, str, str], Awaitable[Ack]]  # robot, cloud, task request id
    stop: Callable[[str, str, str, str], Awaitable[None]]  # mission, robot, cloud, task id
    state_of: Callable[[str], State | None]  # a robot's latest state, any cloud
    publish: Callable[[MissionRecord], None]


class MissionRunner:
    def __init__(self, record: MissionRecord, ports: Ports) -> None:
        self.record = record
        self.ports = ports
        self._turn = asyncio.Lock()
        self._failed: set[str] = set()  # robots that failed this mission: never planned again
        # Task id -> its own duration (robot seconds), for the tasks that have one.
        self._durations = {
            t.id: t.duration for t in record.mission.tasks if t.duration is not None
        }
        self.ended = asyncio.Event()

    @property
    def id(self) -> str:
        return self.record.id

    # -- the events ---------------------------------------------------------------

    async def begin(self) -> None:
        """Plan the mission and send the first assigns (or reject it)."""
        async with self._turn:
            record = self.record
            for n, task in enumerate(record.mission.tasks, start=1):
                record.tasks[n] = TaskRun(n, task.id, (task.location[0], task.location[1]))
            await self._plan("planned")
            if not is_final(record.state):
                await self._advance_all()
            self._publish()

    async def report(self, state: State) -> None:
        async with self._turn:
            if is_final(self.record.state):
                return
            member = self.record.robots.get(state.id)
            if member is None or member.state in ("released", "failed"):
                return
            await self._on_report(member, state)
            self._publish()

    async def tick(self) -> None:
        """Deferred assigns, the watchdog, the tasks' progress (a few times a second)."""
        async with self._turn:
            if is_final(self.record.state):
                return
            before = (self.record.state, self.record.updated_at)
            await self._on_tick()
            changed = before != (self.record.state, self.record.updated_at)
            if changed or any(r.state == "work" for r in self.record.tasks.values()):
                self._publish()

    async def cancel(self) -> None:
        async with self._turn:
            if is_final(self.record.state):
                return
            await self._end("canceled", "canceled by the application", reason=None)
            self._publish()

    async def lost(self, robot_id: str, why: str) -> None:
        """The mission lost a robot by another's word (its home ended the loan)."""
        async with self._turn:
            member = self.record.robots.get(robot_id)
            if is_final(self.record.state) or member is None:
                return
            if member.state not in ("released", "failed"):
                await self._robot_failed(member, why)
                self._publish()

    async def fail_inside(self, reason: str) -> None:
        """Something of this IaaS broke while carrying the mission out: it fails, robots stop."""
        async with self._turn:
            if not is_final(self.record.state):
                await self._end("failed", reason)
                self._publish()

    # -- planning -------------------------------------------------------------------

    async def _plan(self, why: str) -> None:
        """Plan the tasks not started yet, hold the robots, adopt the plan."""
        record, ports = self.record, self.ports
        now = ports.wall()
        replan = record.started_at is not None
        offset = 0.0
        if record.started_at is not None:
            offset = (now - record.started_at) * ports.rules.time_scale
        part, numbers = replan_input(record.mission, record.tasks, [])
        if not part.tasks:
            return
        ours, busy_for = self._own_robots(now)
        taken: set[str] = set()
        for _ in range(ATTEMPTS):
            exclude = self._failed | set(ours) | taken
            others = await ports.gather(record.mission, exclude)
            robots = {r.id: r for r in [*ours.values(), *others]}
            try:
                problem = problem_for(list(robots.values()), part, busy_for)
            except InvalidInput as error:
                await self._end("rejected" if not replan else "failed", error.message)
                return
            if replan or problem.uncoverable() is not None:  # (no plan at all: said at once)
                plan = ports.quick(problem)
            else:
                plan = await ports.plan(problem, record.time_limit)
            if plan.schedule is None:
                why_not = plan.reason or "no plan serves every task."
                if replan:
                    await self._end("failed", f"the tasks left could not be re-planned: {why_not}")
                else:
                    await self._end("rejected", why_not)
                return
            chosen = {
                problem.robot_ids[i]
                for i, sequence in enumerate(plan.schedule.sequences)
                if sequence
            }
            new = [(r, robots[r].cloud) for r in sorted(chosen - set(ours))]
            refused = await ports.hold(record.id, new) if new else []
            if refused:
                taken |= set(refused)
                record.note(
                    ports.wall(),
                    f"{', '.join(sorted(refused)[:10])} taken meanwhile: planning again",
                )
                continue
            break
        else:
            await self._end(
                "failed" if replan else "rejected",
                f"the robots chosen were taken by others {ATTEMPTS} times in a row.",
            )
            return
        now = ports.wall()
        if not replan:
            # Time 0 of the plan: now, once it is made and its robots held (idle where
            # the gather found them); not when planning began, time_limit ago at most,
            # which would have put every robot behind its plan from the start.
            record.started_at = now
        holds = {r: self._holds(r) for r in chosen - set(ours)}
        for member in record.robots.values():
            del member.legs[member.sent :]  # the legs not sent are this plan's now
        adopt(
            problem, plan, part, numbers, robots, record.tasks, record.robots, offset, holds,
            busy_for,
        )
        for robot_id in chosen - set(ours):  # (again) the mission's
            member = record.robots[robot_id]
            if member.state == "released":
                member.state, member.joined_wall = "assigned", 0.0
        for robot_id in set(ours) - chosen:  # re-planned out of the mission
            member = record.robots[robot_id]
            if member.next_leg is None and member.state not in ("working",):
                await self._release(member, "the re-plan needs it no more")
        version = (record.plan or {}).get("version", 0) + 1
        record.plan = {
            **plan_summary(plan, version, now, offset),
            "method": plan.method,
            "elapsed_s": plan.elapsed_s,
        }
        if replan:
            record.note(now, f"re-planned (version {version}, {plan.elapsed_s:.2f} s): {why}")
        else:
            record.note(
                now,
                f"planned in {plan.elapsed_s:.2f} s: makespan {plan.schedule.makespan:.1f} s "
                f"with {len(chosen)} robots",
                "underway",
            )

    def _own_robots(self, now: float) -> tuple[dict[str, Robot], dict[str, float]]:
        """The mission's robots still held, as robots where they are now, and for those
        working on a task, how many robot seconds it still takes."""
        ours: dict[str, Robot] = {}
        busy_for: dict[str, float] = {}
        for member in self.record.robots.values():
            if member.state in ("released", "failed"):
                continue
            state = self.ports.state_of(member.id)
            if state is None:
                continue
            ours[member.id] = state.to_robot("idle")
            leg = member.current
            run = self.record.tasks[leg.task] if leg is not None else None
            if run is not None and run.state == "work" and member.id not in run.done_by:
                began = run.started_wall if run.started_wall is not None else now
                left = (run.end - run.start) - (now - began) * self.ports.rules.time_scale
                busy_for[member.id] = max(0.0, left)
        return ours, busy_for

    def _holds(self, robot_id: str) -> bool:
        state = self.ports.state_of(robot_id)
        return state is not None and state.holds

    # -- carrying it out ------------------------------------------------------------

    async def _advance_all(self) -> None:
        for member in list(self.record.robots.values()):
            await self._advance(member)

    async def _advance(self, member: RobotRun) -> None:
        """Send the robot its next task when it is free for it, or release it after its last."""
        if member.state in ("released", "failed"):
            return
        current = member.current
        run = self.record.tasks[current.task] if current is not None else None
        if run is not None and run.state not in OVER and (
            member.id not in run.done_by or self._stays(run)
        ):
            return  # still on it, or done with its part and staying for the task's duration
        leg = member.next_leg
        if leg is None:
            await self._release(member, "its last task is done")
            return
        now = self.ports.wall()
        if not member.joined_wall:
            member.joined_wall = now
        state = self.ports.state_of(member.id)
        if state is None and now - member.joined_wall < PROTOCOL_WAIT:
            member.state = "assigned"
            return  # a borrowed robot not heard yet: its protocol is not known (tick)
        member.holds = state is not None and state.holds
        if not member.holds and not self._due(member, leg.task, leg.start):
            member.state = "assigned"
            return  # a robot that cannot wait on command goes later (tick)
        await self._send(member)

    def _due(self, member: RobotRun, number: int, start: float) -> bool:
        """Whether a robot that works on arrival should leave now for task ``number``.

        A borrowed robot goes at once: its home lends it only briefly until it
        is dispatched (``--lease-max``)."""
        record = self.record
        assert record.started_at is not None
        if member.cloud != self.ports.cloud:
            return True
        state = self.ports.state_of(member.id)
        position = (
            (state.position[0], state.position[1]) if state is not None else member.position
        )
        travel = travel_seconds(position, record.tasks[number].location, member.speed)
        leave_at = record.started_at + (start - travel) / self.ports.rules.time_scale
        return self.ports.wall() >= leave_at

    async def _send(self, member: RobotRun) -> None:
        record, ports = self.record, self.ports
        leg = member.next_leg
        assert leg is not None
        run = record.tasks[leg.task]
        wire = run.wire(record.id)
        member.sent += 1
        member.sent_wall = member.progressed_wall = ports.wall()
        member.progress = 0.0
        heard = ports.state_of(member.id)
        member.sent_after = heard
        member.state = "travel"
        ports.route(record.id, member.id, wire)
        command = Assign(
            request_id=wire,
            location=list(run.location),
            capabilities=run.uses[member.id],
            execution=record.mission.execution,
            hold=member.holds,
        )
        ack = await ports.assign(member.id, member.cloud, command)
        if not ack.ok:
            await self._robot_failed(member, f"it refused task {run.id}: {ack.error}")
            return
        if run.state == "pending":
            run.state = "travel"

    async def _on_report(self, member: RobotRun, state: State) -> None:
        now = self.ports.wall()
        member.heard_wall = now
        member.position = (state.position[0], state.position[1])
        leg = member.current
        if leg is None:
            return
        if member.sent_after is not None and not state.is_newer_than(member.sent_after):
            # Sent before its current assign: "work" on the task id of a task since
            # planned again is not this leg's.
            return
        run = self.record.tasks[leg.task]
        wire = run.wire(self.record.id)
        task = state.task if state.task is not None and state.task.request_id == wire else None
        if task is None and state.last_task is not None and state.last_task.request_id == wire:
            task = state.last_task
        if task is None:
            if state.status == "offline":
                await self._robot_failed(member, "it went offline")
            return
        if task.phase == "failed" or state.status == "offline":
            said = f": {task.reason}" if task.reason else ""
            await self._robot_failed(member, f"it reported task {run.id} failed{said}")
            return
        if member.id in run.done_by:
            return
        moved_to = MEMBER_STATE.get(task.phase)
        if task.progress > member.progress + 1e-9 or (moved_to and moved_to != member.state):
            member.progress, member.progressed_wall = task.progress, now
        if task.phase == "travel":
            member.state = "travel"
        elif task.phase == "waiting":
            member.state = "waiting"
            if run.state == "work":  # started meanwhile (a member that works on arrival)
                await self._start_members(run, [member])
                return
            if run.state in ("pending", "travel"):
                run.state = "waiting"
            await self._maybe_start(run)
        elif task.phase == "work":
            member.state = "working"
            if run.state in NOT_STARTED:
                # A robot of protocol 1.0 or 1.1 works on arrival: the others start too.
                run.state = "work"
                run.started_wall = now
                others = [record_member for r in run.robots
                          if (record_member := self.record.robots.get(r)) is not None
                          and record_member is not member]
                await self._start_members(run, others)
        elif task.phase == "done":
            run.done_by.add(member.id)
            await self._task_maybe_done(run)
            await self._advance(member)

    async def _maybe_start(self, run: TaskRun) -> None:
        """Start the task's work once every member is there and its predecessors are done."""
        record = self.record
        if run.state not in NOT_STARTED:
            return
        members = [record.robots[r] for r in run.robots if r in record.robots]
        there = all(
            m.current is not None and m.current.task == run.number and m.state == "waiting"
            for m in members
            if m.holds
        )
        if not there or any(m.state == "travel" and not m.holds for m in members):
            return
        before = {a for a, b in record.mission.precedence if b == run.id}
        if any(r.state != "done" for r in record.tasks.values() if r.id in before):
            return
        run.state = "work"
        run.started_wall = self.ports.wall()
        await self._start_members(run, members)

    async def _start_members(self, run: TaskRun, members: list[RobotRun]) -> None:
        """Send ``start`` to the members that hold and are sent to this task (there or not)."""
        record = self.record
        wire = run.wire(record.id)
        told = [
            m for m in members
            if m.holds and m.current is not None and m.current.task == run.number
            and m.state not in ("released", "failed")
        ]
        acks = await asyncio.gather(*(self.ports.start(m.id, m.cloud, wire) for m in told))
        for member, ack in zip(told, acks, strict=True):
            if not ack.ok:
                await self._robot_failed(member, f"it refused to start task {run.id}: {ack.error}")

    async def _task_maybe_done(self, run: TaskRun) -> None:
        record = self.record
        left = [
            r for r in run.robots
            if r not in run.done_by and record.robots.get(r) is not None
            and record.robots[r].state != "failed"
        ]
        if left or self._stays(run):
            return
        run.state, run.progress = "done", 1.0
        record.note(self.ports.wall(), f"task {run.id} done")
        if all(r.state == "done" for r in record.tasks.values()):
            await self._end("completed", "every task is done", reason=None)
            return
        # Its members go on: those that stayed for its duration too, whoever ended it.
        for robot_id in run.robots:
            member = record.robots.get(robot_id)
            if member is not None:
                await self._advance(member)
        # A task whose predecessors just finished may start now.
        for other in record.tasks.values():
            if other.state == "waiting":
                await self._maybe_start(other)

    def _stays(self, run: TaskRun) -> bool:
        """Whether a task with a duration of its own still keeps its members at its place.

        docs/model.md: every member stays until ``end_k = start_k + duration``,
        even when its capabilities' work is shorter and it reports done sooner.
        """
        duration = self._durations.get(run.id)
        if duration is None or run.started_wall is None:
            return False
        elapsed = (self.ports.wall() - run.started_wall) * self.ports.rules.time_scale
        return elapsed < duration

    async def _on_tick(self) -> None:
        record, ports, rules = self.record, self.ports, self.ports.rules
        now = ports.wall()
        for run in list(record.tasks.values()):
            if run.state == "work" and run.done_by and not self._stays(run):
                # A task that kept its members for its duration: over once it has passed.
                await self._task_maybe_done(run)
                if is_final(record.state):
                    return
        for member in list(record.robots.values()):
            if member.state == "assigned":
                await self._advance(member)
                continue
            leg = member.current
            if member.state in ("released", "failed") or leg is None:
                continue
            run = record.tasks[leg.task]
            if member.id in run.done_by:
                continue
            why = self._late(member, run, now)
            if why is not None:
                await self._robot_failed(member, why)
                if is_final(record.state):
                    return
        for run in record.tasks.values():
            if run.state == "work" and run.started_wall is not None:
                length = max(run.end - run.start, 1e-9)
                done = (now - run.started_wall) * rules.time_scale / length
                run.progress = min(1.0, max(run.progress, done))

    def _late(self, member: RobotRun, run: TaskRun, now: float) -> str | None:
        """Why the watchdog counts the robot failed now, or None (lifecycle's rule)."""
        rules = self.ports.rules
        silent = now - max(member.heard_wall, member.sent_wall or 0.0)
        still = now - member.progressed_wall if member.state in ("travel", "working") else None
        if member.state == "travel" and member.sent_wall is not None:
            leg = member.current
            assert leg is not None
            expected = max(leg.arrive - leg.depart, 0.0)
            failed = rules.failure(
                silent, member.sent_wall, expected, now, still, f"arrival at task {run.id}"
            )
        elif member.state == "working" and run.started_wall is not None:
            expected = max(run.end - run.start, 0.0)
            failed = rules.failure(
                silent, run.started_wall, expected, now, still, f"finish of task {run.id}"
            )
        else:
            failed = rules.failure(silent, None, 0.0, now, None)
        return failed[1] if failed is not None else None

    async def _robot_failed(self, member: RobotRun, why: str) -> None:
        record = self.record
        now = self.ports.wall()
        self._failed.add(member.id)
        member.state = "failed"
        record.note(now, f"robot {member.id} failed: {why}")
        leg = member.current
        await self.ports.stop(
            record.id, member.id, member.cloud,
            record.tasks[leg.task].wire(record.id) if leg is not None else record.id,
        )
        await self.ports.release(record.id, member.id, member.cloud, f"it failed: {why}")
        for run in record.tasks.values():
            if run.state == "work" and member.id in run.robots and member.id not in run.done_by:
                # Its part of the work is not done, so the task is not: it is planned
                # again, whole, with the tasks not started (its other members are
                # stopped by the re-plan, and may be chosen again).
                run.state, run.progress, run.started_wall = "pending", 0.0, None
                run.done_by.clear()
                record.note(now, f"task {run.id} is planned again: {member.id} left it unfinished")
        await self._replan(f"robot {member.id} failed")

    async def _replan(self, why: str) -> None:
        """Plan again the tasks not started: their robots stop where they are first."""
        record = self.record
        for member in record.robots.values():
            leg = member.current
            if member.state in ("released", "failed") or leg is None:
                continue
            run = record.tasks[leg.task]
            if run.state in NOT_STARTED and member.id not in run.done_by:
                await self.ports.stop(record.id, member.id, member.cloud, run.wire(record.id))
                member.sent -= 1  # that leg is planned again
                member.state = "assigned"
                if member.cloud != self.ports.cloud:
                    # Stopping it at its home ended its loan: it is given back, and
                    # borrowed again if the new plan takes it.
                    await self._release(member, "given back for a re-plan")
        for run in record.tasks.values():
            if run.state in NOT_STARTED:
                run.state, run.progress = "pending", 0.0
        await self._plan(why)
        if not is_final(record.state):
            await self._advance_all()

    async def _release(self, member: RobotRun, why: str) -> None:
        if member.state in ("released", "failed"):
            return
        member.state = "released"
        await self.ports.release(self.record.id, member.id, member.cloud, why)

    async def _end(self, state: str, note: str, reason: str | None = "") -> None:
        """The mission ends: every robot still on it is stopped (unless done) and released."""
        record = self.record
        now = self.ports.wall()
        for member in record.robots.values():
            if member.state in ("released", "failed"):
                continue
            leg = member.current
            run = record.tasks[leg.task] if leg is not None else None
            if run is not None and member.id not in run.done_by and run.state not in OVER:
                await self.ports.stop(record.id, member.id, member.cloud, run.wire(record.id))
            await self._release(member, note)
        for run in record.tasks.values():
            if run.state not in OVER:
                run.state = "canceled"
        record.reason = note if reason == "" else reason
        record.note(now, note, state)
        self.ended.set()

    def _publish(self) -> None:
        self.ports.publish(self.record)


def robot_of(record: Any) -> Robot:
    """A remote robot (a ``RobotRecord`` of an idle reply) as a ``Robot``."""
    import msgspec

    if isinstance(record, Robot):
        return record
    return Robot.model_validate(msgspec.to_builtins(record), strict=False)

