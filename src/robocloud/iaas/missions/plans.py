"""A mission's plan as the IaaS carries it out: each task's run, each robot's legs.

Times of a plan are robot seconds from the mission's ``started_at`` (time 0
of its first plan; a wall second is ``time_scale`` robot seconds). A
re-plan (``replan_input``) plans only the tasks not yet started, from where
the robots are now: a robot still working on a task starts as if it were
``left * speed`` metres further away, ``left`` being the robot seconds its
work still takes (so it is free when it could really leave), and the new
plan's times are shifted by the robot seconds since ``started_at``
(``adopt``). Tasks already started keep their coalition and their times.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any

from robocloud.domain import Robot
from robocloud.domain.mission_ids import task_request_id
from robocloud.fleet.messages import State
from robocloud.planning.bounds import lower_bound
from robocloud.planning.construction import best_construction
from robocloud.planning.mission import Mission, MissionInput, MissionTask, to_problem
from robocloud.planning.plan import Plan
from robocloud.planning.problem import Problem

# A task not started yet (it may still be re-planned) and a task underway or over.
NOT_STARTED = frozenset({"pending", "travel", "waiting"})
OVER = frozenset({"done", "failed", "canceled"})


@dataclass
class TaskRun:
    """One task of the mission as it is carried out."""

    number: int  # from 1, in the mission's order: its robots are told ``<mission>.<number>``
    id: str
    location: tuple[float, float]
    robots: list[str] = field(default_factory=list)
    uses: dict[str, list[str]] = field(default_factory=dict)  # robot -> capabilities used there
    start: float = 0.0  # plan times
    end: float = 0.0
    state: str = "pending"
    progress: float = 0.0
    started_wall: float | None = None  # when its work began (the start command, or a report)
    done_by: set[str] = field(default_factory=set)

    def wire(self, mission_id: str) -> str:
        return task_request_id(mission_id, self.number)


@dataclass
class Leg:
    task: int  # the task's number
    depart: float
    arrive: float
    start: float
    end: float


@dataclass
class RobotRun:
    """One robot of the mission: its route, and where it is on it."""

    id: str
    cloud: str
    origin: tuple[float, float]  # where its part began (the plan's ``from``)
    speed: float
    holds: bool  # it speaks protocol 1.2: assigns are sent with hold, the work starts on start
    legs: list[Leg] = field(default_factory=list)
    home_at: float = 0.0
    state: str = "assigned"
    sent: int = 0  # legs sent so far (the current one is ``legs[sent - 1]``)
    sent_wall: float | None = None  # when the current leg's assign was sent
    # The robot's newest state when that assign was sent: a state no newer
    # (State.is_newer_than) is from before it (a re-planned task's ids repeat).
    sent_after: State | None = None
    heard_wall: float = 0.0  # its latest report
    # Its current task's progress and when it last grew (or its phase changed): the
    # watchdog's stall rule (lifecycle.Rules.failure).
    progress: float = 0.0
    progressed_wall: float = 0.0
    joined_wall: float = 0.0  # when the mission took it
    position: tuple[float, float] = (0.0, 0.0)

    @property
    def current(self) -> Leg | None:
        return self.legs[self.sent - 1] if self.sent else None

    @property
    def next_leg(self) -> Leg | None:
        return self.legs[self.sent] if self.sent < len(self.legs) else None


def mission_input(robots: list[Robot], mission: Mission) -> MissionInput:
    return MissionInput(robots=robots, mission=mission)


def replan_input(
    mission: Mission, runs: dict[int, TaskRun], robots: list[Robot]
) -> tuple[Mission, dict[str, int]]:
    """The mission of the tasks not started yet (precedence among them), and their numbers.

    A pair whose first task is underway is left out: the runner itself
    starts no task before its predecessors are done.
    """
    pending = [t for t in mission.tasks if runs[_number(mission, t)].state in NOT_STARTED]
    names = {t.id for t in pending}
    precedence = [(a, b) for a, b in mission.precedence if a in names and b in names]
    part = mission.model_copy(update={"tasks": pending, "precedence": precedence})
    return part, {t.id: _number(mission, t) for t in pending}


def _number(mission: Mission, task: MissionTask) -> int:
    return mission.tasks.index(task) + 1


def problem_for(
    robots: list[Robot], mission: Mission, busy_for: dict[str, float]
) -> Problem:
    """The planning problem: ``robots`` (made idle: the mission's own are busy), each robot
    of ``busy_for`` free only after that many robot seconds."""
    idle = [r.model_copy(update={"status": "idle"}) for r in robots]
    problem = to_problem(mission_input(idle, mission))
    if not busy_for:
        return problem
    start = tuple(
        tuple(d + busy_for.get(problem.robot_ids[i], 0.0) * problem.speed[i] for d in row)
        for i, row in enumerate(problem.start_distance)
    )
    return dataclasses.replace(problem, start_distance=start)


def adopt(
    problem: Problem,
    plan: Plan,
    mission: Mission,
    numbers: dict[str, int],
    robots: dict[str, Robot],
    runs: dict[int, TaskRun],
    members: dict[str, RobotRun],
    offset: float,
    holds: dict[str, bool],
    busy_for: dict[str, float],
) -> None:
    """Put the plan's tasks and legs into ``runs`` and ``members`` (times shifted by
    ``offset``): the tasks it planned get their coalition and times, each robot its
    new legs after those it keeps."""
    schedule = plan.schedule
    assert schedule is not None
    by_id = {t.id: t for t in mission.tasks}
    for k, name in enumerate(problem.task_ids):
        run = runs[numbers[name]]
        required = by_id[name].required
        run.robots = [problem.robot_ids[i] for i in schedule.coalitions[k]]
        run.uses = {
            problem.robot_ids[i]: [c for c in required if c in problem.brings[i]]
            for i in schedule.coalitions[k]
        }
        run.start = offset + schedule.start[k]
        run.end = offset + schedule.end[k]
        run.state, run.progress, run.done_by = "pending", 0.0, set()
    for i, sequence in enumerate(schedule.sequences):
        robot_id = problem.robot_ids[i]
        if not sequence and robot_id not in members:
            continue  # planned no task: not part of the mission
        robot = robots[robot_id]
        member = members.get(robot_id)
        if member is None:
            position = (robot.position[0], robot.position[1])
            member = members[robot_id] = RobotRun(
                robot_id, robot.cloud, position, robot.speed, holds.get(robot_id, False),
                position=position,
            )
        # Legs already sent stay; the rest are this plan's.
        del member.legs[member.sent :]
        previous: int | None = None
        for k in sequence:
            depart = offset + (
                busy_for.get(robot_id, 0.0) if previous is None else schedule.end[previous]
            )
            arrive = offset + (
                problem.travel_from_start(i, k)
                if previous is None
                else schedule.end[previous] + problem.travel_between(i, previous, k)
            )
            member.legs.append(
                Leg(numbers[problem.task_ids[k]], depart, arrive, offset + schedule.start[k],
                    offset + schedule.end[k])
            )
            previous = k
        member.home_at = offset + schedule.arrival[i] if sequence else member.home_at


def quick_plan(problem: Problem) -> Plan:
    """The planner's construction (``planning.construction``) with its analytic lower
    bound: what a re-plan takes, in this process, in milliseconds."""
    started = time.perf_counter()
    missing = problem.uncoverable()
    if missing is not None:
        k, capability = missing
        return Plan(None, None, False, "anytime", time.perf_counter() - started,
                    f"task {problem.task_ids[k]} needs {problem.need[k][capability]} robots "
                    f"bringing {capability!r}, and too few of the robots left do.")
    schedule = best_construction(problem)
    bound = lower_bound(problem) if schedule is not None else None
    if schedule is not None and bound is not None:
        bound = min(bound, schedule.makespan)
    return Plan(schedule, bound, False, "anytime", time.perf_counter() - started,
                None if schedule is not None else "no plan serves every task.")


def plan_summary(plan: Plan, version: int, planned_at: float, offset: float) -> dict[str, Any]:
    schedule = plan.schedule
    makespan = None if schedule is None else offset + schedule.makespan
    bound = None if plan.lower_bound is None else offset + plan.lower_bound
    return {
        "version": version,
        "planned_at": planned_at,
        "makespan": makespan,
        "lower_bound": bound,
        "gap": plan.gap,
        "optimal": plan.optimal,
    }


def travel_seconds(a: tuple[float, float], b: tuple[float, float], speed: float) -> float:
    return math.dist(a, b) / speed
