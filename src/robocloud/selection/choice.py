"""The final choice (end of thesis Algorithm 4): PROMETHEE II over the front.

"If we have more than one Pareto optimal solution at the end of the
iterations, we select among them based on the Promethee II ranking method
giving the same importance (weight) for all criteria (time, cost, and number
of robots)." MODEL.md fixes the rest: usual criterion, all three minimised,
highest net flow wins, ties by smaller C, then T, then N, then the sorted id
list.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from robocloud.domain import Coalition
from robocloud.selection.promethee import usual_net_flows


def choose(front: Sequence[Coalition]) -> Coalition | None:
    if not front:
        return None
    matrix = np.array([[c.time, c.cost, float(c.size)] for c in front])
    phi = usual_net_flows(matrix, np.full(3, 1 / 3), np.ones(3, dtype=bool))
    # Flows are sums of multiples of 1/(3(n-1)): rounding only merges values
    # that differ by floating point noise.
    best = round(float(phi.max()), 9)
    tied = [c for c, f in zip(front, phi, strict=True) if round(float(f), 9) == best]
    return min(tied, key=lambda c: (c.cost, c.time, c.size, c.robots))


def within_thresholds(
    front: Sequence[Coalition], max_time: float, max_cost: float
) -> list[Coalition]:
    """Algorithm 4, step 18: drop the coalitions over the time and cost thresholds."""
    return [
        c
        for c in front
        if c.time <= max_time + max(1e-6, 1e-9 * abs(c.time))
        and c.cost <= max_cost + max(1e-6, 1e-9 * abs(c.cost))
    ]
