"""The baseline: the tasks one by one, each by today's single-task selection.

In a precedence-respecting order (``Problem.topological_order``), each task
gets the coalition robocloud's selection chooses for it alone
(``selection.pipeline.select_problem``, the exact optimizer and the
PROMETHEE II choice, weighted by the mission's priority): every robot able
to help is a candidate, with ``t_i`` the drive from where its previous task
leaves it plus its work there, and ``c_i`` that drive's cost plus its
capabilities' cost, as MODEL.md defines them for one task. Like a series of
single requests, the selection does not know when a robot will be free, nor
what the later tasks need: that is what planning the mission jointly gains,
and what the benchmark measures.
"""

from __future__ import annotations

import numpy as np

from robocloud.domain import Task
from robocloud.domain.task import MAX_COST, MAX_ROBOTS, MAX_TIME
from robocloud.planning.problem import Problem
from robocloud.planning.schedule import Schedule, pruned, timed
from robocloud.selection.pipeline import select_problem
from robocloud.selection.problem import CoalitionProblem, RobotTerms


def greedy(problem: Problem) -> Schedule | None:
    """The baseline plan (None when some task has no feasible coalition)."""
    order = problem.topological_order()
    assert order is not None  # the readers refuse cycles
    place: list[int | None] = [None] * problem.n_robots
    coalitions: list[tuple[int, ...]] = [()] * problem.n_tasks
    sequences: list[list[int]] = [[] for _ in range(problem.n_robots)]
    for k in order:
        candidates = [i for i in range(problem.n_robots) if problem.useful[i][k]]
        names = tuple(problem.need[k])
        drive = [
            problem.start_distance[i][k] if place[i] is None
            else problem.task_distance[place[i]][k]  # type: ignore[index]
            for i in candidates
        ]
        terms = RobotTerms(
            time=np.array(
                [d / problem.speed[i] + problem.work[i][k]
                 for d, i in zip(drive, candidates, strict=True)], dtype=np.float64
            ),
            cost=np.array(
                [d * problem.travel_cost_per_m[i] + problem.use_cost[i][k]
                 for d, i in zip(drive, candidates, strict=True)], dtype=np.float64
            ),
            uses=np.array(
                [[c in problem.brings[i] for c in names] for i in candidates], dtype=bool
            ).reshape(len(candidates), len(names)),
            capabilities=names,
        )
        task = Task(
            location=[0.0, 0.0],
            sensing=dict(problem.need[k]),
            max_robots=MAX_ROBOTS,
            max_cost=MAX_COST,
            max_time=MAX_TIME,
            priority=problem.priority,
        )
        ids = tuple(str(i) for i in candidates)
        result = select_problem(
            CoalitionProblem.of_terms(ids, terms, task), task, "exact", budget_s=None,
            ranking=False,
        )
        if result.chosen is None:
            return None
        members = tuple(sorted(int(r) for r in result.chosen.robots))
        coalitions[k] = members
        for i in members:
            sequences[i].append(k)
            place[i] = k
    schedule = timed(problem, coalitions, sequences)
    assert schedule is not None  # appended in a precedence order: no cycle
    return pruned(problem, schedule)
