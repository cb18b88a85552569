"""A reference front from a plain MILP per step (HiGHS through scipy), for large instances.

Independent of the exact optimizer's covering code: one binary per robot, no
classes, no Lagrangian enumeration. For a size limit n and a time limit tau
(robots slower than tau fixed to 0) three MILPs give the point of the
(T, C) front at tau: the least cost C*, then the least T at cost C*, then the
least N at (C*, T*). The next tau is just below T*. Size limits go down as
in the exact optimizer: (largest N seen) - 1, until a sweep finds nothing.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.optimize import Bounds, LinearConstraint, milp

from robocloud.selection.problem import CoalitionProblem

SLACK = 1e-7  # how far a secondary objective may let the cost drift


def _solve(c: np.ndarray, a: sparse.csr_array, lo: np.ndarray, hi: np.ndarray,
           upper: np.ndarray, integrality: np.ndarray) -> np.ndarray | None:
    result = milp(c, constraints=LinearConstraint(a, lo, hi), bounds=Bounds(0, upper),
                  integrality=integrality, options={"mip_rel_gap": 0.0})
    return None if result.x is None else np.asarray(result.x)


def milp_front(problem: CoalitionProblem) -> set[tuple[float, float, int]]:
    """The (T, C, N) vectors of the front, T and C recomputed from the robots chosen."""
    n_robots = problem.size
    t, cost = problem.time, problem.cost
    ok = (t <= problem.max_time + 1e-6) & (cost <= problem.max_cost + 1e-6)
    uses = problem.uses.astype(float)
    # Variables: y (one per robot), then z = T.
    cover = sparse.hstack([sparse.csr_array(uses.T), sparse.csr_array((uses.shape[1], 1))])
    size_row = np.hstack([np.ones(n_robots), [0.0]])
    cost_row = np.hstack([cost, [0.0]])
    # z >= t_i y_i  <=>  t_i y_i - z <= 0
    time_rows = sparse.hstack([sparse.diags_array(t), -sparse.csr_array(np.ones((n_robots, 1)))])
    integrality = np.hstack([np.ones(n_robots), [0]])
    points: set[tuple[float, float, int]] = set()
    size_limit = min(problem.max_robots, int(problem.need.sum()))
    while size_limit >= 1:
        allowed = ok.copy()
        top = 0
        while True:
            upper = np.hstack([allowed.astype(float), [np.inf]])
            base_a = sparse.vstack([cover, sparse.csr_array(size_row[None, :]),
                                    sparse.csr_array(cost_row[None, :]), time_rows]).tocsr()
            base_lo = np.hstack([problem.need, [0, 0], np.full(n_robots, -np.inf)])
            base_hi = np.hstack([np.full(len(problem.need), np.inf), [size_limit],
                                 [problem.max_cost + 1e-6], np.zeros(n_robots)])
            x = _solve(cost_row, base_a, base_lo, base_hi, upper, integrality)
            if x is None:
                break
            best_cost = float(cost @ (x[:-1] > 0.5))
            hi = base_hi.copy()
            hi[len(problem.need) + 1] = best_cost + SLACK
            x = _solve(np.hstack([np.zeros(n_robots), [1.0]]), base_a, base_lo, hi, upper,
                       integrality)
            assert x is not None
            chosen = x[:-1] > 0.5
            fastest = float(t[chosen].max())
            upper_t = np.hstack([(allowed & (t <= fastest + 1e-9)).astype(float), [np.inf]])
            x = _solve(size_row, base_a, base_lo, hi, upper_t, integrality)
            assert x is not None
            chosen = x[:-1] > 0.5
            points.add((float(t[chosen].max()), float(cost[chosen].sum()), int(chosen.sum())))
            top = max(top, int(chosen.sum()))
            allowed &= t < fastest - max(1e-6, 1e-9 * fastest)
        if top == 0:
            break
        size_limit = top - 1
    return points
