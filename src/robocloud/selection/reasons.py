"""Why no coalition is feasible: the requirement or threshold that could not be met.

First the cheap, sound tests of :mod:`robocloud.selection.feasibility`
(capabilities, the largest count against max_robots, max_time, a covering
bound on the size, a lower bound on the cost). When none fires but the
search found nothing, a cheapest cover decides between max_robots and
max_cost: each check relaxes the thresholds after it, so the first that
fails names the real obstacle. That search is bounded by the selection's
deadline; when the deadline ends it first, the reason says so.
"""

from __future__ import annotations

import dataclasses
import math

from robocloud.domain import Task
from robocloud.selection.budget import NO_DEADLINE, Deadline
from robocloud.selection.exact import cheapest
from robocloud.selection.feasibility import quick_infeasibility, task_kind
from robocloud.selection.problem import CoalitionProblem

__all__ = ["infeasibility_reason", "out_of_time", "task_kind"]


def out_of_time(deadline: Deadline) -> str:
    budget = f"of {deadline.budget_s:g} s " if deadline.budget_s is not None else ""
    return f"the time budget {budget}ran out before a feasible coalition was found."


def infeasibility_reason(
    problem: CoalitionProblem, task: Task, deadline: Deadline = NO_DEADLINE
) -> str:
    quick = quick_infeasibility(problem, task)
    if quick is not None:
        return quick
    cover = cheapest(dataclasses.replace(problem, max_cost=math.inf), deadline=deadline)
    if not cover.proven:
        return out_of_time(deadline)
    if cover.members is None:
        return (
            f"max_robots {task.max_robots:,} cannot be met: every coalition that brings the "
            f"required capabilities in time needs more robots."
        )
    cost = float(problem.cost[cover.members].sum())
    return (
        f"max_cost {task.max_cost:g} cannot be met: the cheapest coalition that brings the "
        f"required capabilities in time costs {cost:.2f}."
    )
