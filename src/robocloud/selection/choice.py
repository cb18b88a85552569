"""The final choice (end of thesis Algorithm 4): PROMETHEE II over the front.

The thesis: "If we have more than one Pareto optimal solution at the end of
the iterations, we select among them based on the Promethee II ranking
method giving the same importance (weight) for all criteria (time, cost,
and number of robots)."

Departure from the thesis (MODEL.md): the weights follow the task's
priority, as they already do in the ranking (Algorithm 3). ``balanced`` keeps
the thesis's equal weights; ``time`` weighs (T, C, N) 0.6/0.2/0.2 and
``cost`` 0.2/0.6/0.2. With equal weights a "time critical" request often got
the slowest coalition on the front (measured in issue 9: 5 of 8 tries), and
users read the priority as applying to the choice too.

MODEL.md fixes the rest: usual criterion, all three minimised, highest net
flow wins, ties by smaller C, then T, then N, then the sorted id list.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from robocloud.domain import Coalition
from robocloud.domain.numeric import margin
from robocloud.errors import InvalidInput
from robocloud.selection.promethee import usual_net_flows, usual_net_flows_small

# Fronts up to this size are weighed in plain Python (the same numbers, faster
# than numpy's per-call cost there).
SMALL_FRONT = 24
# (T, C, N) weights per priority, as MODEL.md fixes them.
CHOICE_WEIGHTS: dict[str, tuple[float, float, float]] = {
    "balanced": (1 / 3, 1 / 3, 1 / 3),
    "time": (0.6, 0.2, 0.2),
    "cost": (0.2, 0.6, 0.2),
}


def choose(front: Sequence[Coalition], priority: str = "balanced") -> Coalition | None:
    weights = CHOICE_WEIGHTS.get(priority)
    if weights is None:
        raise InvalidInput(
            f"priority must be one of {', '.join(CHOICE_WEIGHTS)}, not {priority!r}",
            field="task.priority",
        )
    if not front:
        return None
    rows = [(c.time, c.cost, float(c.size)) for c in front]
    if len(front) <= SMALL_FRONT:
        phi: Sequence[float] = usual_net_flows_small(rows, weights, (True, True, True))
    else:
        phi = usual_net_flows(np.array(rows), np.array(weights), np.ones(3, dtype=bool)).tolist()
    # Flows are sums of multiples of 0.2/(n-1) or 1/(3(n-1)): rounding only
    # merges values that differ by floating point noise.
    best = round(max(phi), 9)
    tied = [c for c, f in zip(front, phi, strict=True) if round(float(f), 9) == best]
    return min(tied, key=lambda c: (c.cost, c.time, c.size, c.robots))


def within_thresholds(
    front: Sequence[Coalition], max_time: float, max_cost: float
) -> list[Coalition]:
    """Algorithm 4, step 18: drop the coalitions over the time and cost thresholds."""
    return [
        c
        for c in front
        if c.time <= max_time + margin(c.time) and c.cost <= max_cost + margin(c.cost)
    ]
