"""The Pareto front of docs/model.md: dominance under the tolerance, one coalition per vector.

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


# Up to this many coalitions, plain Python is faster than numpy's per-call
# cost (benchmarks/results/design-notes.md, small-fronts).
SMALL = 24


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
    if len(pool) <= SMALL:
        return _small_front(pool)
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


def _small_front(pool: list[Coalition]) -> list[Coalition]:
    """``pareto_front``'s loop on a short ``pool`` (already sorted), one pair at a time.

    The same steps and the same float operations as the arrays, so the same answer.
    """
    kept: list[int] = []
    for i, b in enumerate(pool):
        t, c, n = b.time, b.cost, b.size
        skip = False
        for j in kept:
            a = pool[j]
            t_close, c_close = _close_one(t, a.time), _close_one(c, a.cost)
            t_less, c_less = a.time < t and not t_close, a.cost < c and not c_close
            no_worse = (t_less or t_close) and (c_less or c_close) and a.size <= n
            if (no_worse and (t_less or c_less or a.size < n)) or (
                a.size == n and t_close and c_close
            ):
                skip = True
                break
        if skip:
            continue
        survivors = []
        for j in kept:
            a = pool[j]
            t_close, c_close = _close_one(t, a.time), _close_one(c, a.cost)
            t_more, c_more = t < a.time and not t_close, c < a.cost and not c_close
            beaten = (
                (t_more or t_close)
                and (c_more or c_close)
                and n <= a.size
                and (t_more or c_more or n < a.size)
            )
            if not beaten:
                survivors.append(j)
        kept = [*survivors, i]
    result = []
    for i in sorted(kept):
        a = pool[i]
        twins = [
            s
            for s in pool
            if s.size == a.size and _close_one(a.time, s.time) and _close_one(a.cost, s.cost)
        ]
        result.append(min(twins, key=lambda s: s.robots))
    return sorted(result, key=lambda s: (s.time, s.cost, s.size, s.robots))


def _close_one(a: float, b: float) -> bool:
    return abs(a - b) <= max(ABS_TOL, REL_TOL * max(abs(a), abs(b)))
