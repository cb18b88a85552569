"""A mission: several tasks planned together, with precedence and an end place.

docs/model.md ("A mission") fixes the JSON shape and its ranges::

    {"robots": [robot, ...],
     "mission": {"tasks": [{"id": "fire-1", "location": [x, y],
                            "sensing": {"light": 1}, "actuating": {"grabber": 2},
                            "duration": 120.0}, ...],
                 "precedence": [["fire-1", "fire-2"]], "end": [x, y],
                 "priority": "time", "max_time": 3600.0, "min_battery": 70.0,
                 "execution": "parallel"}}

Robots and capabilities are MODEL.md's; :func:`to_problem` filters the robots
as for one task (idle, charged enough, bringing something some task needs)
and turns the rest into a :class:`~robocloud.planning.problem.Problem`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from robocloud.domain import Robot
from robocloud.domain.robot import Name, Position
from robocloud.domain.task import MAX_CAPABILITIES, MAX_TIME, Count, Execution, Priority
from robocloud.errors import InvalidInput
from robocloud.planning.plan import Plan
from robocloud.planning.problem import Problem

# Beyond these a mission is not one fire front but a mistake; the construction
# grows with tasks squared times robots (100 tasks and 1,000 robots: seconds).
MAX_TASKS = 100
MAX_MISSION_ROBOTS = 1_000

Seconds = Annotated[float, Field(ge=0.0, le=MAX_TIME, allow_inf_nan=False)]


class MissionTask(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    id: Name
    location: Position
    sensing: dict[Name, Count] = Field(default_factory=dict, max_length=MAX_CAPABILITIES)
    actuating: dict[Name, Count] = Field(default_factory=dict, max_length=MAX_CAPABILITIES)
    # None: the task lasts as long as its slowest member needs (its capability times).
    duration: Seconds | None = None

    @model_validator(mode="after")
    def _requires_something(self) -> MissionTask:
        if not self.sensing and not self.actuating:
            raise ValueError("a task must require at least one sensing or actuating capability")
        both = sorted(set(self.sensing) & set(self.actuating))
        if both:
            raise ValueError(f"capability {both[0]!r} is listed as both sensing and actuating")
        return self

    @property
    def required(self) -> dict[str, int]:
        merged = {**self.sensing, **self.actuating}
        return {name: merged[name] for name in sorted(merged)}


class Mission(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    tasks: list[MissionTask] = Field(min_length=1, max_length=MAX_TASKS)
    precedence: list[tuple[Name, Name]] = Field(default_factory=list, max_length=10 * MAX_TASKS)
    end: Position | None = None
    priority: Priority = "time"
    max_time: Seconds | None = None
    min_battery: Annotated[float, Field(ge=0.0, le=100.0, allow_inf_nan=False)] = 0.0
    execution: Execution = "parallel"


class MissionInput(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    robots: list[Robot] = Field(max_length=MAX_MISSION_ROBOTS)
    mission: Mission


def candidates(robots: list[Robot], mission: Mission) -> list[Robot]:
    """The robots a mission may use: idle, charged enough, bringing something it needs."""
    wanted = {name for task in mission.tasks for name in task.required}
    return [
        r for r in robots
        if r.status == "idle" and r.battery >= mission.min_battery
        and wanted & set(r.capabilities)
    ]


def work_and_cost(
    robot: Robot, required: Mapping[str, int], duration: float | None, execution: str
) -> tuple[float, float]:
    """How long ``robot`` keeps a task going, and what its capabilities cost there.

    The time is the task's ``duration``, or the capability times of what the
    robot uses there (their longest in parallel, their sum in sequence);
    math.inf when it brings nothing the task needs.
    """
    used = [robot.capabilities[c] for c in required if c in robot.capabilities]
    if not used:
        return math.inf, 0.0
    cost = sum(c.cost for c in used)
    if duration is not None:
        return duration, cost
    times = [c.time for c in used]
    return (max(times) if execution == "parallel" else sum(times)), cost


def to_problem(document: MissionInput) -> Problem:
    mission = document.mission
    ids = [r.id for r in document.robots]
    if len(set(ids)) != len(ids):
        twice = next(i for i in ids if ids.count(i) > 1)
        raise InvalidInput(f"robots: id {twice!r} is used twice.", "robots")
    robots = candidates(document.robots, mission)
    tasks = mission.tasks
    index: dict[str, int] = {}
    for k, task in enumerate(tasks):
        if task.id in index:
            raise InvalidInput(f"mission.tasks[{k}].id: {task.id!r} is the id of an earlier "
                               "task too.", f"mission.tasks[{k}].id")
        index[task.id] = k
    for n, (before, after) in enumerate(mission.precedence):
        field = f"mission.precedence[{n}]"
        for name in (before, after):
            if name not in index:
                raise InvalidInput(f"{field} names {name!r}, which is no task of the mission.",
                                   field)
        if before == after:
            raise InvalidInput(f"{field} puts task {before!r} before itself.", field)
    end = mission.end
    required = [t.required for t in tasks]
    terms = [
        [work_and_cost(r, required[k], t.duration, mission.execution) for k, t in enumerate(tasks)]
        for r in robots
    ]
    problem = Problem(
        robot_ids=tuple(r.id for r in robots),
        task_ids=tuple(t.id for t in tasks),
        brings=tuple(frozenset(r.capabilities) for r in robots),
        need=tuple(required),
        task_distance=tuple(
            tuple(math.dist(a.location, b.location) for b in tasks) for a in tasks
        ),
        start_distance=tuple(
            tuple(math.dist(r.position, t.location) for t in tasks) for r in robots
        ),
        end_distance=None if end is None else tuple(math.dist(t.location, end) for t in tasks),
        # A robot the plan leaves out is no part of the mission: it goes nowhere.
        start_end_distance=None,
        speed=tuple(r.speed for r in robots),
        work=tuple(tuple(w for w, _ in row) for row in terms),
        use_cost=tuple(tuple(c for _, c in row) for row in terms),
        travel_cost_per_m=tuple(r.travel_cost_per_m for r in robots),
        precedence=tuple((index[a], index[b]) for a, b in mission.precedence),
        priority=mission.priority,
        max_time=mission.max_time,
    )
    if problem.topological_order() is None:
        raise InvalidInput(
            "mission.precedence forms a cycle: no task of it could start first.",
            "mission.precedence",
        )
    return problem


def plan_document(problem: Problem, plan: Plan) -> dict[str, Any]:
    """``robocloud plan``'s output for a mission (docs/model.md, "A mission")."""
    schedule = plan.schedule
    status = "infeasible" if schedule is None else "optimal" if plan.optimal else "feasible"
    document: dict[str, Any] = {
        "status": status,
        "method": plan.method,
        "makespan": None if schedule is None else schedule.makespan,
        "cost": None if schedule is None else schedule.cost,
        "lower_bound": plan.lower_bound,
        "gap": plan.gap,
        "elapsed_s": plan.elapsed_s,
        "reason": plan.reason,
        "tasks": [],
        "routes": {},
    }
    if schedule is None:
        return document
    document["tasks"] = [
        {
            "id": problem.task_ids[k],
            "robots": [problem.robot_ids[i] for i in schedule.coalitions[k]],
            "start": schedule.start[k],
            "end": schedule.end[k],
        }
        for k in range(problem.n_tasks)
    ]
    routes: dict[str, list[dict[str, Any]]] = {}
    for i, sequence in enumerate(schedule.sequences):
        steps = []
        previous: int | None = None
        for k in sequence:
            arrive = (
                problem.travel_from_start(i, k)
                if previous is None
                else schedule.end[previous] + problem.travel_between(i, previous, k)
            )
            steps.append({
                "task": problem.task_ids[k],
                "arrive": arrive,
                "start": schedule.start[k],
                "end": schedule.end[k],
            })
            previous = k
        routes[problem.robot_ids[i]] = steps
    document["routes"] = routes
    return document
