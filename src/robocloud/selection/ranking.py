"""Ranking (thesis Algorithm 3): PROMETHEE II over the candidates.

The criteria are each robot's t_i and c_i, both minimised under the usual
criterion; the task's priority (the thesis's Criteria_Importance) picks the
weights. Candidates are ranked by net flow phi, ties by robot id.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from robocloud.errors import InvalidInput
from robocloud.selection.problem import CoalitionProblem
from robocloud.selection.promethee import rank_order, usual_net_flows

# (time weight, cost weight) per priority, as docs/model.md fixes them.
PRIORITY_WEIGHTS: dict[str, tuple[float, float]] = {
    "balanced": (0.5, 0.5),
    "time": (0.75, 0.25),
    "cost": (0.25, 0.75),
}


def rank_candidates(
    problem: CoalitionProblem, priority: str
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
    """(order, phi): indices into ``problem.ids``, best first, and each net flow."""
    weights = PRIORITY_WEIGHTS.get(priority)
    if weights is None:
        raise InvalidInput(
            f"priority must be one of {', '.join(PRIORITY_WEIGHTS)}, not {priority!r}",
            field="task.priority",
        )
    matrix = np.column_stack([problem.time, problem.cost])
    phi = usual_net_flows(matrix, weights, (True, True))
    order = np.asarray(rank_order(problem.ids, phi), dtype=np.int64)
    return order, phi
