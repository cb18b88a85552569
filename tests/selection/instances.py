"""Random small coalition problems, with values on a coarse grid so ties happen."""

from __future__ import annotations

import numpy as np

from robocloud.selection.problem import CoalitionProblem


def random_problem(rng: np.random.Generator, n: int | None = None) -> CoalitionProblem:
    n = int(rng.integers(1, 17)) if n is None else n
    k = int(rng.integers(1, 4))
    need = rng.integers(1, 4, size=k)
    uses = rng.random((n, k)) < rng.uniform(0.25, 0.7)
    if rng.random() < 0.5:
        # Coarse values: many exact ties in time and cost.
        time = rng.integers(1, 8, size=n).astype(float) * 10
        cost = rng.integers(1, 8, size=n).astype(float)
    else:
        time = np.round(rng.uniform(10, 100, size=n), 2)
        cost = np.round(rng.uniform(1, 20, size=n), 2)
    tight = rng.random() < 0.5
    return CoalitionProblem(
        ids=tuple(f"r-{i:02d}" for i in rng.permutation(n)),
        time=time,
        cost=cost,
        uses=uses,
        capabilities=tuple(f"cap{j}" for j in range(k)),
        need=need.astype(np.int64),
        max_robots=int(rng.integers(1, n + 1)) if tight else n,
        max_cost=float(rng.uniform(5, 40)) if tight else 1e9,
        max_time=float(rng.uniform(20, 80)) if tight else 1e9,
    )
