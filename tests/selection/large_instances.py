"""Coalition problems needing 20 to 60 robots, for checks against the MILP reference."""

from __future__ import annotations

import numpy as np

from robocloud.selection.problem import CoalitionProblem


def fleet_problem(seed: int, robots: int, counts: tuple[int, int, int, int],
                  max_time: float = 400.0) -> CoalitionProblem:
    """Like the wildfire fleet: each robot brings one of two actuators (A or B) and
    maybe the sensors S and U; a sensor adds to the time and cost it brings."""
    rng = np.random.default_rng(seed)
    uses = np.zeros((robots, 4), dtype=bool)
    uses[np.arange(robots), rng.integers(0, 2, robots)] = True
    uses[:, 2] = rng.random(robots) < 0.35
    uses[:, 3] = rng.random(robots) < 0.3
    time = np.round(rng.uniform(20, 500, robots) + 10 * uses[:, 2:].sum(axis=1), 2)
    quality = rng.uniform(0, 1, robots)
    cost = np.round(4 + 8 * quality + rng.uniform(0.5, 3, robots) * uses[:, 2:].sum(axis=1), 2)
    return CoalitionProblem(
        ids=tuple(f"r-{i:04d}" for i in rng.permutation(robots)),
        time=time,
        cost=cost,
        uses=uses,
        capabilities=("A", "B", "S", "U"),
        need=np.array(counts, dtype=np.int64),
        max_robots=counts[0] + counts[1] + 10,
        max_cost=1e6,
        max_time=max_time,
    )


def mixed_problem(seed: int, robots: int, counts: tuple[int, int, int]) -> CoalitionProblem:
    """Any capability set: fronts that also trade the coalition's size."""
    rng = np.random.default_rng(seed)
    k = len(counts)
    uses = rng.random((robots, k)) < rng.uniform(0.3, 0.6, k)
    uses[~uses.any(axis=1), 0] = True
    time = np.round(rng.uniform(10, 500, robots), 2)
    cost = np.round(rng.uniform(1, 5, robots) * uses.sum(axis=1) + rng.uniform(0, 4, robots), 2)
    return CoalitionProblem(
        ids=tuple(f"r-{i:04d}" for i in rng.permutation(robots)),
        time=time,
        cost=cost,
        uses=uses,
        capabilities=tuple(f"c{j}" for j in range(k)),
        need=np.array(counts, dtype=np.int64),
        max_robots=int(sum(counts)) + 5,
        max_cost=1e9,
        max_time=300.0,
    )
