"""Cheap infeasibility first: sound tests that answer before any optimisation.

Each test is linear in the candidates (a count, a sort or a partition per
capability) and allocates nothing that grows with the requested counts, so
an absurd request ("10,000 grabbers") is answered at once with the reason.
Every test is sound: when it fires, no feasible coalition exists. Where it
does not fire the optimizer decides.

Not used, because it is not sound: "the counts add up to more than
max_robots". One robot may bring several capabilities, so a task needing 3
lights and 3 grabbers can be met by 3 robots. The sound tests on size are
the largest count alone, and a covering bound: the fewest robots whose
numbers of required capabilities add up to the sum of the counts.
"""

from __future__ import annotations

import numpy as np

from robocloud.domain import Task
from robocloud.domain.numeric import ABS_TOL, REL_TOL
from robocloud.selection.problem import CoalitionProblem


def _robots(count: int) -> str:
    return f"{count:,} robot{'s' if count != 1 else ''}"


def task_kind(task: Task, name: str) -> str:
    return "sensing" if name in task.sensing else "actuating"


def quick_infeasibility(problem: CoalitionProblem, task: Task) -> str | None:
    """A sentence naming the obstacle when a cheap test proves the task infeasible."""
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
    widest = int(np.argmax(problem.need))
    if problem.need[widest] > problem.max_robots:
        name = problem.capabilities[widest]
        return (
            f"max_robots {task.max_robots:,} cannot be met: {task_kind(task, name)} capability "
            f"{name!r} alone needs {_robots(int(problem.need[widest]))}."
        )
    in_time = problem.time <= problem.max_time + max(ABS_TOL, REL_TOL * problem.max_time)
    reachable = problem.uses[in_time].sum(axis=0)
    for name, need, have in zip(problem.capabilities, problem.need, reachable, strict=True):
        if have < need:
            return (
                f"max_time {task.max_time:g} s cannot be met: {task_kind(task, name)} capability "
                f"{name!r} needs {_robots(int(need))}, and only {_robots(int(have))} can reach "
                f"the location and do the work in time."
            )
    uses = problem.uses[in_time]
    brought = np.sort(uses.sum(axis=1))[::-1]
    total = int(problem.need.sum())
    fewest = int(np.searchsorted(np.cumsum(brought), total, side="left")) + 1
    if fewest > problem.max_robots:
        return (
            f"max_robots {task.max_robots:,} cannot be met: the robots that can reach the "
            f"location in time bring at most {int(brought[0])} of the required capabilities "
            f"each, so a coalition needs at least {_robots(fewest)}."
        )
    least = least_cost(problem, in_time)
    if least > problem.max_cost + max(ABS_TOL, REL_TOL * least):
        return (
            f"max_cost {task.max_cost:g} cannot be met: the cheapest coalition that brings the "
            f"required capabilities in time costs {least:.2f} or more."
        )
    return None


def least_cost(problem: CoalitionProblem, allowed: np.ndarray) -> float:
    """A lower bound on the cost of any feasible coalition of the ``allowed`` robots.

    Each robot's cost is shared equally among the required capabilities it
    brings; a coalition pays, for every capability k, at least the need_k
    smallest shares among the carriers of k.
    """
    uses = problem.uses[allowed]
    share = problem.cost[allowed] / np.maximum(uses.sum(axis=1), 1)
    total = 0.0
    for k, q in enumerate(problem.need.tolist()):
        shares = share[uses[:, k]]
        total += float(np.partition(shares, q - 1)[:q].sum()) if q < shares.size else float(
            shares.sum()
        )
    return total
