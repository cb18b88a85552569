"""Why no coalition is feasible: the requirement or threshold that could not be met.

Each check relaxes the thresholds that come after it, so the first one that
fails names the real obstacle: the capabilities the candidates bring at all,
then max_time, then max_robots, then max_cost.
"""

from __future__ import annotations

import dataclasses
import math

from robocloud.domain import Task
from robocloud.selection.exact import cheapest_cover, within_thresholds
from robocloud.selection.problem import CoalitionProblem


def _robots(count: int) -> str:
    return f"{count} robot{'s' if count != 1 else ''}"


def infeasibility_reason(problem: CoalitionProblem, task: Task) -> str:
    filter_text = f"idle with battery at or above {task.min_battery:g}%"
    if problem.size == 0:
        return f"no robot that is {filter_text} brings any required capability."
    carriers = problem.uses.sum(axis=0)
    for name, need, have in zip(problem.capabilities, problem.need, carriers, strict=True):
        if have < need:
            return (
                f"{task_kind(task, name)} capability {name!r} needs {_robots(int(need))}, "
                f"but only {_robots(int(have))} {filter_text} bring it."
            )
    in_time = dataclasses.replace(problem, max_cost=math.inf, max_robots=int(problem.need.sum()))
    fast = in_time.subproblem(within_thresholds(in_time))
    reachable = fast.uses.sum(axis=0)
    for name, need, have in zip(problem.capabilities, problem.need, reachable, strict=True):
        if have < need:
            return (
                f"max_time {task.max_time:g} s cannot be met: {task_kind(task, name)} capability "
                f"{name!r} needs {_robots(int(need))}, and only {_robots(int(have))} can reach "
                f"the location and do the work in time."
            )
    cheapest = cheapest_cover(dataclasses.replace(problem, max_cost=math.inf))
    if cheapest is None:
        return (
            f"max_robots {task.max_robots} cannot be met: every coalition that brings the "
            f"required capabilities in time needs more robots."
        )
    cost = float(problem.cost[cheapest].sum())
    return (
        f"max_cost {task.max_cost:g} cannot be met: the cheapest coalition that brings the "
        f"required capabilities in time costs {cost:.2f}."
    )


def task_kind(task: Task, name: str) -> str:
    return "sensing" if name in task.sensing else "actuating"
