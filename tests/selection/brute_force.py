"""Reference answers by enumerating every coalition: the oracle for small instances."""

from __future__ import annotations

import itertools

import numpy as np

from robocloud.domain import Coalition
from robocloud.selection.pareto import pareto_front
from robocloud.selection.problem import CoalitionProblem


def all_feasible_rows(problem: CoalitionProblem) -> np.ndarray:
    rows = np.array(list(itertools.product((False, True), repeat=problem.size)), dtype=bool)
    return rows[problem.feasible(rows)]


def brute_force_front(problem: CoalitionProblem) -> list[Coalition]:
    """Every feasible coalition, then docs/model.md's front.

    Before the quadratic ``pareto_front``, a loose filter keeps only
    coalitions whose cost is within 1e-6 of the cheapest one that is no
    slower (within 1e-6) and no larger: every front member and every twin of
    one passes it.
    """
    rows = all_feasible_rows(problem)
    if rows.size == 0:
        return []
    time, cost, size = problem.evaluate(rows)
    order = np.argsort(time, kind="stable")
    time, cost, size, rows = time[order], cost[order], size[order], rows[order]
    keep = np.zeros(len(rows), dtype=bool)
    reach = np.searchsorted(time, time + 1e-6 + 1e-9 * np.abs(time), side="right")
    for n in np.unique(size):
        prefix = np.minimum.accumulate(np.where(size <= n, cost, np.inf))
        mine = size == n
        keep |= mine & (cost <= prefix[reach - 1] + 1e-6 + 1e-9 * np.abs(cost))
    return pareto_front(problem.coalition(np.flatnonzero(row)) for row in rows[keep])
