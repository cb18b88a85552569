"""The final choice (end of thesis Algorithm 4): PROMETHEE II over the front.

The thesis: "If we have more than one Pareto optimal solution at the end of
the iterations, we select among them based on the Promethee II ranking
method giving the same importance (weight) for all criteria (time, cost,
and number of robots)."

Departures from the thesis (docs/model.md, "The choice"):

- The weights follow the task's priority, as they already do in the ranking
  (Algorithm 3). ``balanced`` keeps the thesis's equal weights; ``time``
  weighs (T, C, N) 0.6/0.2/0.2 and ``cost`` 0.2/0.6/0.2. With equal weights a
  "time critical" request often got the slowest coalition on the front
  (benchmarks/results/design-notes.md, choice-weights).
- Each criterion is the V-shape criterion (PROMETHEE type 3) whose preference
  threshold p_j is the criterion's range over the front, not the usual
  criterion: on a front where every member trades time for cost at one size,
  the usual criterion gives every member the same net flow, and the tie rule
  then picked the cheapest end whatever the priority (issue 26: a balanced
  request got 19 min for 137.81 when 11 min 47 s cost 140.20).

All three criteria are minimised; the highest net flow wins; ties (flows
equal under docs/model.md's tolerance) go to the smaller C, then T, then N, then
the sorted id list.
"""

from __future__ import annotations

from collections.abc import Sequence

from robocloud.domain import Coalition
from robocloud.domain.numeric import isclose, margin
from robocloud.errors import InvalidInput
from robocloud.selection.promethee import (
    range_vshape_net_flows,
    range_vshape_parts,
    weighted_parts,
)

# (T, C, N) weights per priority, as docs/model.md fixes them.
CHOICE_WEIGHTS: dict[str, tuple[float, float, float]] = {
    "balanced": (1 / 3, 1 / 3, 1 / 3),
    "time": (0.6, 0.2, 0.2),
    "cost": (0.2, 0.6, 0.2),
}


def weights_of(priority: str) -> tuple[float, float, float]:
    weights = CHOICE_WEIGHTS.get(priority)
    if weights is None:
        raise InvalidInput(
            f"priority must be one of {', '.join(CHOICE_WEIGHTS)}, not {priority!r}",
            field="task.priority",
        )
    return weights


def choice_flows(front: Sequence[Coalition], priority: str = "balanced") -> list[float]:
    """phi of each member of the front, as the choice for ``priority`` weighs it."""
    return range_vshape_net_flows(_rows(front), weights_of(priority))


def choose_index(front: Sequence[Coalition], priority: str = "balanced") -> int | None:
    """The index in ``front`` of the coalition ``priority`` chooses; None for no front."""
    return _best(front, choice_flows(front, priority))


def choose(front: Sequence[Coalition], priority: str = "balanced") -> Coalition | None:
    index = choose_index(front, priority)
    return None if index is None else front[index]


def choices(front: Sequence[Coalition]) -> dict[str, int] | None:
    """priority -> the index in ``front`` of what that priority chooses (None: no front).

    What the API shows beside a request's front, so a user sees where the
    other priorities would have chosen. The three share one scaling of the front.
    """
    if not front:
        return None
    parts = range_vshape_parts(_rows(front), 3)
    out: dict[str, int] = {}
    for priority, weights in CHOICE_WEIGHTS.items():
        index = _best(front, weighted_parts(parts, weights, len(front)))
        assert index is not None  # a front that is not empty always has a choice
        out[priority] = index
    return out


def _rows(front: Sequence[Coalition]) -> list[tuple[float, float, float]]:
    return [(c.time, c.cost, float(c.size)) for c in front]


def _best(front: Sequence[Coalition], phi: Sequence[float]) -> int | None:
    """The highest phi; ties (equal under docs/model.md's tolerance) by C, T, N, ids."""
    if not phi:
        return None
    best = max(phi)
    tied = [i for i, f in enumerate(phi) if isclose(f, best)]
    return min(tied, key=lambda i: _tie_key(front[i]))


def _tie_key(c: Coalition) -> tuple[float, float, int, tuple[str, ...]]:
    return (c.cost, c.time, c.size, c.robots)


def within_thresholds(
    front: Sequence[Coalition], max_time: float, max_cost: float
) -> list[Coalition]:
    """Algorithm 4, step 18: drop the coalitions over the time and cost thresholds."""
    return [
        c
        for c in front
        if c.time <= max_time + margin(c.time) and c.cost <= max_cost + margin(c.cost)
    ]
