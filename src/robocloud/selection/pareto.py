"""The Pareto front of MODEL.md: dominance under the tolerance, one coalition per vector.

A coalition weakly dominates another when it is no worse in T, C and N
(``<=`` under the tolerance) and better in one (``<``). Where several
coalitions share a vector, the one whose sorted id list is lexicographically
smallest stands for it. The front is sorted by time, then cost, then size.
"""

from __future__ import annotations

from collections.abc import Iterable

from robocloud.domain import Coalition
from robocloud.domain.numeric import isclose, less, less_equal


def dominates(a: Coalition, b: Coalition) -> bool:
    if not (less_equal(a.time, b.time) and less_equal(a.cost, b.cost) and a.size <= b.size):
        return False
    return less(a.time, b.time) or less(a.cost, b.cost) or a.size < b.size


def same_vector(a: Coalition, b: Coalition) -> bool:
    return a.size == b.size and isclose(a.time, b.time) and isclose(a.cost, b.cost)


def pareto_front(coalitions: Iterable[Coalition]) -> list[Coalition]:
    """The non-dominated coalitions, one per vector, sorted by (T, C, N).

    Quadratic in the number of coalitions; optimizers hand it at most a few
    hundred.
    """
    # Sorting by (C, T, N, ids) first means a kept coalition is never dominated
    # by a later one except within the tolerance, and the first of a vector is
    # its lexicographically smallest member.
    pool = sorted(set(coalitions), key=lambda s: (s.cost, s.time, s.size, s.robots))
    front: list[Coalition] = []
    for candidate in pool:
        if any(dominates(kept, candidate) or same_vector(kept, candidate) for kept in front):
            continue
        # Within the tolerance a later coalition can still dominate a kept one.
        front = [kept for kept in front if not dominates(candidate, kept)]
        front.append(candidate)
    # Costs equal under the tolerance may sort either way: a vector is
    # represented by the smallest id list among all the coalitions sharing it.
    result = [
        min((s for s in pool if same_vector(s, kept)), key=lambda s: s.robots) for kept in front
    ]
    return sorted(result, key=lambda s: (s.time, s.cost, s.size, s.robots))
