"""The Pareto front of MODEL.md: dominance under the tolerance, one coalition per vector.

A coalition weakly dominates another when it is no worse in T, C and N
(``<=`` under the tolerance) and better in one (``<``). Where several
coalitions share a vector, the one whose sorted id list is lexicographically
smallest stands for it. The front is sorted by time, then cost, then size.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import numpy.typing as npt

from robocloud.domain import Coalition
from robocloud.domain.numeric import ABS_TOL, REL_TOL, isclose, less, less_equal

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


def dominates(a: Coalition, b: Coalition) -> bool:
    if not (less_equal(a.time, b.time) and less_equal(a.cost, b.cost) and a.size <= b.size):
        return False
    return less(a.time, b.time) or less(a.cost, b.cost) or a.size < b.size


def same_vector(a: Coalition, b: Coalition) -> bool:
    return a.size == b.size and isclose(a.time, b.time) and isclose(a.cost, b.cost)


def _close(a: float, b: FloatArray) -> BoolArray:
    return np.asarray(np.abs(a - b) <= np.maximum(ABS_TOL, REL_TOL * np.maximum(abs(a), np.abs(b))))


def pareto_front(coalitions: Iterable[Coalition]) -> list[Coalition]:
    """The non-dominated coalitions, one per vector, sorted by (T, C, N).

    Each candidate is compared with the kept ones as arrays, so a sweep's few
    thousand candidates stay cheap; the rule is the pairwise one of
    ``dominates`` and ``same_vector``.
    """
    # Sorting by (C, T, N, ids) first means a kept coalition is never dominated
    # by a later one except within the tolerance, and the first of a vector is
    # its lexicographically smallest member.
    pool = sorted(set(coalitions), key=lambda s: (s.cost, s.time, s.size, s.robots))
    if not pool:
        return []
    time = np.array([s.time for s in pool])
    cost = np.array([s.cost for s in pool])
    size = np.array([s.size for s in pool])
    kept = np.zeros(len(pool), dtype=bool)
    for i in range(len(pool)):
        t, c, n = time[i], cost[i], size[i]
        at = np.flatnonzero(kept)
        kt, kc, kn = time[at], cost[at], size[at]
        t_close, c_close = _close(t, kt), _close(c, kc)
        t_less, c_less = (kt < t) & ~t_close, (kc < c) & ~c_close
        no_worse = (t_less | t_close) & (c_less | c_close) & (kn <= n)
        same = (kn == n) & t_close & c_close
        if (no_worse & (t_less | c_less | (kn < n))).any() or same.any():
            continue
        # Within the tolerance a later coalition can still dominate a kept one.
        t_more, c_more = (t < kt) & ~t_close, (c < kc) & ~c_close
        beaten = (t_more | t_close) & (c_more | c_close) & (n <= kn) & (t_more | c_more | (n < kn))
        kept[at[beaten]] = False
        kept[i] = True
    # Costs equal under the tolerance may sort either way: a vector is
    # represented by the smallest id list among all the coalitions sharing it.
    result = []
    for i in np.flatnonzero(kept).tolist():
        twins = np.flatnonzero((size == size[i]) & _close(time[i], time) & _close(cost[i], cost))
        result.append(min((pool[j] for j in twins.tolist()), key=lambda s: s.robots))
    return sorted(result, key=lambda s: (s.time, s.cost, s.size, s.robots))
