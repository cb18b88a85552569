"""Random MRTA-Benchmark instances of any size, drawn as the dataset's are.

The distributions follow the MRTA-Benchmark dataset (Jakob Bichler, TU Delft,
DOI 10.4121/10e28ee0-9ad9-450d-8be7-6e6a91f2931f, CC BY 4.0) as its README
describes them: places with integer coordinates on a 100 x 100 grid (the
start and end depots too), travel time the Euclidean distance, durations of
50 to 99, 3 skills, each robot with a non-empty random set of skills and
every skill held by some robot, each task needing a non-empty random set of
skills; precedence pairs between distinct tasks, without cycles (the dataset
has one pair for 8 tasks; here one per 8 tasks, at least one).
"""

from __future__ import annotations

import math
import random
from typing import Any

SKILLS = 3
GRID = 100


def _subset(rng: random.Random) -> list[int]:
    while True:
        flags = [rng.randint(0, 1) for _ in range(SKILLS)]
        if any(flags):
            return flags


def generate(n_tasks: int, n_robots: int, seed: int) -> dict[str, Any]:
    """An instance in the dataset's own format (``read_instance`` reads it)."""
    rng = random.Random(seed)
    while True:
        q = [_subset(rng) for _ in range(n_robots)]
        if all(any(row[s] for row in q) for s in range(SKILLS)):
            break
    places = n_tasks + 2
    locations = [[rng.randint(0, GRID), rng.randint(0, GRID)] for _ in range(places)]
    r = [[0.0] * SKILLS] + [[float(f) for f in _subset(rng)] for _ in range(n_tasks)]
    r.append([0.0] * SKILLS)
    durations = [0] + [rng.randint(50, 99) for _ in range(n_tasks)] + [0]
    travel = [
        [math.dist(a, b) for b in locations] for a in locations
    ]
    pairs: list[list[int]] = []
    # j < k in a random numbering of the tasks: never a cycle.
    rank = list(range(1, n_tasks + 1))
    rng.shuffle(rank)
    while len(pairs) < max(1, n_tasks // 8) and n_tasks >= 2:
        a, b = sorted(rng.sample(range(n_tasks), 2))
        pair = [rank[a], rank[b]]
        if pair not in pairs:
            pairs.append(pair)
    return {
        "Q": q,
        "R": r,
        "T_e": durations,
        "T_t": travel,
        "task_locations": locations,
        "precedence_constraints": pairs or None,
    }
