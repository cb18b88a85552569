"""The pool: the best ranked candidates that the swarm searches.

The thesis takes the first max_robots robots of the PROMETHEE II ranking
("the algorithm selects the first 50 robots"). A ranking by single robots can
leave out every robot that brings a rare capability, so the pool is widened
with a witness: the robots of a cheap feasible coalition over all the
candidates. If the candidates allow any feasible coalition, the pool holds
one whenever the witness search could prove it.

No step here is exponential: the witness is a cheapest cover searched with
at most ``POOL_NODES`` branch-and-bound nodes (each one linear program and a
bounded enumeration), and where that limit or the deadline ends the search
first, a greedy cover stands in. ``seed_covers`` gives MOPSO cheap covers
under a few time limits the same way.
"""

from __future__ import annotations

import numpy as np

from robocloud.domain.numeric import ABS_TOL, REL_TOL
from robocloud.selection.budget import NO_DEADLINE, Deadline
from robocloud.selection.covering import CoverSolver
from robocloud.selection.exact import cheapest, prune
from robocloud.selection.problem import CoalitionProblem, IntArray

# Branch-and-bound nodes a pool's cover search may use.
POOL_NODES = 64
# How many time limits ``seed_covers`` tries.
SEED_COVERS = 8


def build_pool(
    problem: CoalitionProblem,
    order: IntArray,
    size: int,
    survivors: IntArray | None = None,
    deadline: Deadline = NO_DEADLINE,
    extra: list[IntArray] | None = None,
) -> IntArray:
    """Indices into ``problem``: the first ``size`` of ``order``, then the
    witness's robots, best ranked first.

    ``extra`` (from ``seed_covers``, whose first cover is the witness) stands
    in for the witness search when given.
    """
    top = [int(i) for i in order[: max(size, 0)]]
    chosen = set(top)
    if extra is None:
        witness = cover_witness(problem, survivors, deadline)
        extra = [witness] if witness is not None else []
    more: set[int] = set()
    for coalition in extra:
        more |= {int(i) for i in coalition}
    rank = {int(i): r for r, i in enumerate(order)}
    top += sorted((i for i in more if i not in chosen), key=rank.__getitem__)
    return np.array(top, dtype=np.int64)


def cover_witness(
    problem: CoalitionProblem, survivors: IntArray | None = None, deadline: Deadline = NO_DEADLINE
) -> IntArray | None:
    """A cheapest feasible coalition, or a greedy cover when the bounded search ends first."""
    cover = cheapest(problem, survivors, deadline, POOL_NODES)
    if cover.members is not None or cover.proven:
        return cover.members
    return greedy_cover(problem, prune(problem) if survivors is None else survivors)


def greedy_cover(problem: CoalitionProblem, robots: IntArray) -> IntArray | None:
    """Robots taken one at a time by cost per capability still short; None if they cannot cover.

    Linear in the robots per step and at most sum(need) steps. It ignores
    max_robots and max_cost, so its coalition may break them: it only stands
    in for a witness.
    """
    short = problem.need.astype(np.int64).copy()
    uses = problem.uses[robots].astype(np.int64)
    cost = problem.cost[robots] + ABS_TOL
    free = np.ones(robots.size, dtype=bool)
    taken: list[int] = []
    while (short > 0).any():
        useful = uses @ (short > 0)
        score = np.where(free & (useful > 0), useful / cost, -1.0)
        best = int(np.argmax(score))
        if score[best] <= 0:
            return None
        free[best] = False
        taken.append(int(robots[best]))
        short -= uses[best]
    return np.sort(np.array(taken, dtype=np.int64))


def seed_covers(
    problem: CoalitionProblem, survivors: IntArray, deadline: Deadline = NO_DEADLINE
) -> list[IntArray]:
    """The witness, then cheapest covers under time limits spread over the candidates' times.

    The first cover is ``cover_witness``'s (all robots allowed). Then up to
    ``SEED_COVERS`` - 1 tighter time limits, each search bounded like the
    witness's; the first limit whose search finds nothing ends the list (a
    tighter one allows even fewer robots). MOPSO starts from these, spread
    along the time-cost trade-off.
    """
    if survivors.size == 0 or problem.largest_useful_coalition < 1:
        return []
    solver = CoverSolver(problem, survivors, deadline)
    times = np.sort(problem.time[survivors])
    limits = np.quantile(times, np.linspace(1.0, 0.0, SEED_COVERS, endpoint=False))
    limits[0] = np.inf
    covers: list[IntArray] = []
    affordable = problem.max_cost + max(ABS_TOL, REL_TOL * problem.max_cost)
    for step, limit in enumerate(limits.tolist()):
        if deadline.expired():
            break
        if step:
            solver.allow_faster_than(limit + max(ABS_TOL, REL_TOL * abs(limit)) * 2)
        result = solver.solve(problem.largest_useful_coalition, POOL_NODES)
        members = solver.coalition(result.ties[0]) if result.ties else None
        if step == 0 and members is None and result.status == "cut":
            members = greedy_cover(problem, survivors)
        if members is None or (step and problem.cost[members].sum() > affordable):
            break
        covers.append(members)
    return covers
