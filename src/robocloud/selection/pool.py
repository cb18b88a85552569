"""The pool: the best ranked candidates that the swarm searches.

The thesis takes the first max_robots robots of the PROMETHEE II ranking
("the algorithm selects the first 50 robots"). A ranking by single robots can
leave out every robot that brings a rare capability, so the pool is widened
with a witness: the robots of a cheapest feasible coalition over all the
candidates. If the candidates allow any feasible coalition, the pool holds
one.
"""

from __future__ import annotations

import numpy as np

from robocloud.selection.exact import cheapest_cover
from robocloud.selection.problem import CoalitionProblem, IntArray


def build_pool(
    problem: CoalitionProblem, order: IntArray, size: int, survivors: IntArray | None = None
) -> IntArray:
    """Indices into ``problem``: the first ``size`` of ``order``, then the witness, best first."""
    top = [int(i) for i in order[: max(size, 0)]]
    chosen = set(top)
    witness = cheapest_cover(problem, survivors)
    if witness is not None:
        rank = {int(i): r for r, i in enumerate(order)}
        top += sorted((int(i) for i in witness if int(i) not in chosen), key=rank.__getitem__)
    return np.array(top, dtype=np.int64)
