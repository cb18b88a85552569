"""PROMETHEE II, the outranking method of thesis Algorithm 3 (Ranking).

Each criterion compares two alternatives through a preference function
P_j(a, b) in [0, 1] of the deviation d = g_j(a) - g_j(b) (negated for a
minimised criterion); pi(a, b) = sum_j w_j P_j(a, b) with the weights
normalised by their sum, and

    phi+(a) = sum_{b != a} pi(a, b) / (n - 1)     (how much a outranks)
    phi-(a) = sum_{b != a} pi(b, a) / (n - 1)     (how much a is outranked)
    phi(a)  = phi+(a) - phi-(a)                   (the net flow; 0 when n = 1)

The six generalised criteria of Brans & Vincke are offered under pymcdm's
names ('usual', 'ushape', 'vshape', 'level', 'vshape_2') plus 'gaussian',
with pymcdm's conventions for q and p so the two agree.

The general path never holds an n-by-n matrix: it walks row blocks, so memory
stays O(block * n). When every criterion is usual (MODEL.md's ranking), the
flows are counts of strictly better and strictly worse alternatives, found by
sorting in O(n log n) per criterion. The final choice's criteria (V-shape,
p = the range over the front) reduce to a weighted sum: see
``range_vshape_net_flows``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, NamedTuple, get_args

import numpy as np
import numpy.typing as npt

from robocloud.domain.numeric import isclose, margin_array

FloatArray = npt.NDArray[np.float64]
Preference = Literal["usual", "ushape", "vshape", "level", "vshape_2", "gaussian"]
PREFERENCES: tuple[str, ...] = get_args(Preference)

# Elements of one (block, n) deviation table: 8 MiB of float64.
_BLOCK_ELEMENTS = 1 << 20


@dataclass(frozen=True)
class Criterion:
    """One column of the decision matrix: its weight, direction and preference
    function. ``q`` is the indifference and ``p`` the preference threshold;
    ``s`` the Gaussian's inflection point."""

    weight: float
    minimize: bool = True
    preference: Preference = "usual"
    q: float = 0.0
    p: float = 0.0
    s: float = 0.0

    def __post_init__(self) -> None:
        if self.preference not in PREFERENCES:
            raise ValueError(f"unknown preference function {self.preference!r}")
        if not (np.isfinite(self.weight) and self.weight >= 0):
            raise ValueError("a criterion's weight must be finite and non-negative")
        if self.q < 0:
            raise ValueError("the indifference threshold q must be non-negative")
        if self.preference == "vshape" and self.p <= 0:
            raise ValueError("the V-shape criterion needs p > 0")
        if self.preference in ("level", "vshape_2") and self.p <= self.q:
            raise ValueError(f"the {self.preference} criterion needs p > q")
        if self.preference == "gaussian" and self.s <= 0:
            raise ValueError("the Gaussian criterion needs s > 0")


class Flows(NamedTuple):
    positive: FloatArray  # phi+
    negative: FloatArray  # phi-
    net: FloatArray  # phi


def _threshold(x: FloatArray) -> FloatArray:
    """An alternative with value x (maximised) strictly beats every value below this.

    MODEL.md's tolerance is max(1e-6, 1e-9 * max(|a|, |b|)); here it is the
    preferred value's own max(1e-6, 1e-9 * |a|) so that a sort can count it.
    The two differ only when |d| lies within about 1e-18 * |a| of the
    threshold, below the resolution of a float64, and using one rule in both
    paths keeps the fast and the general path in exact agreement.
    """
    return np.asarray(x - margin_array(x))


def _preference(criterion: Criterion, d: FloatArray) -> FloatArray:
    """P(d) for the deviations of every preference function but usual."""
    q, p, s = criterion.q, criterion.p, criterion.s
    kind = criterion.preference
    with np.errstate(divide="ignore", invalid="ignore"):
        if kind == "ushape":
            out = np.where(d > q, 1.0, 0.0)
        elif kind == "vshape":
            out = np.where(d > p, 1.0, np.where(d > 0, d / p, 0.0))
        elif kind == "level":
            out = np.where(d > p, 1.0, np.where(d > q, 0.5, 0.0))
        elif kind == "vshape_2":
            out = np.where(d > p, 1.0, np.where(d > q, (d - q) / (p - q), 0.0))
        else:  # gaussian
            out = np.where(d > 0, -np.expm1(-(d * d) / (2.0 * s * s)), 0.0)
    return np.asarray(out, dtype=np.float64)


def _prepare(
    matrix: npt.ArrayLike, weights: npt.ArrayLike, minimize: npt.ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Columns turned into values to maximise, and weights summing to one."""
    values = np.asarray(matrix, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    lower = np.asarray(minimize, dtype=bool).reshape(-1)
    if values.ndim != 2 or values.shape[1] != len(w) or len(w) != len(lower):
        raise ValueError("the matrix needs one column per criterion")
    if len(w) == 0 or not np.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
        raise ValueError("weights must be non-negative with a positive sum")
    if not np.isfinite(values).all():
        raise ValueError("the matrix must hold finite values")
    # Negation is exact, so x(a) - x(b) equals g(b) - g(a) bit for bit.
    sign = np.where(lower, -1.0, 1.0)
    return values * sign, w / w.sum()


def _usual_flows(x: FloatArray, w: FloatArray) -> Flows:
    n = x.shape[0]
    positive = np.zeros(n)
    negative = np.zeros(n)
    for j in range(x.shape[1]):
        # Work in sorted order: searchsorted is several times faster with
        # sorted needles, and t(x) is non-decreasing in x.
        order = np.argsort(x[:, j])
        column = x[order, j]
        threshold = _threshold(column)
        # worse(a) = #{b : x(b) < t(a)};  better(a) = #{b : t(b) > x(a)}.
        # Both count the same pairs, so the net flows sum to zero (up to rounding).
        worse = np.searchsorted(column, threshold, side="left")
        better = n - np.searchsorted(np.sort(threshold), column, side="right")
        positive[order] += w[j] * worse
        negative[order] += w[j] * better
    return _scaled(positive, negative, n)


def _scaled(positive: FloatArray, negative: FloatArray, n: int) -> Flows:
    if n > 1:
        positive, negative = positive / (n - 1), negative / (n - 1)
    return Flows(positive, negative, positive - negative)


def usual_net_flows(
    matrix: npt.ArrayLike, weights: npt.ArrayLike, minimize: npt.ArrayLike
) -> FloatArray:
    """phi under the usual criterion for every column, in O(n log n) per column.

    A tie within MODEL.md's tolerance is no preference (see ``_threshold``).
    """
    x, w = _prepare(matrix, weights, minimize)
    return _usual_flows(x, w).net


def range_vshape_net_flows(
    rows: Sequence[Sequence[float]], weights: Sequence[float]
) -> list[float]:
    """phi with every criterion minimised and V-shaped, p_j = its range over ``rows``.

    MODEL.md's final choice. For criterion j let ``lo_j`` and ``p_j`` be the
    smallest value and the range (max minus min) of its column; a range
    within MODEL.md's tolerance (``isclose(max, min)``) counts for nothing.
    The V-shape criterion with threshold p_j is
    ``P_j(a, b) = min(1, max(0, (g_j(b) - g_j(a)) / p_j))``; no deviation
    exceeds the range, so with ``h_j(a) = (g_j(a) - lo_j) / p_j`` in [0, 1],
    ``P_j(a, b) = max(0, h_j(b) - h_j(a))`` and, as ``max(0, x) - max(0, -x) = x``,

        pi(a, b) - pi(b, a) = sum_j w_j (h_j(b) - h_j(a)).

    Summed over the n - 1 other rows,
    ``phi(a) = sum_j w_j (H_j - n h_j(a)) / (n - 1)`` with ``H_j = sum_b h_j(b)``:
    O(n) per criterion, with no pair table. The net flow is an affine
    function of the weighted sum of normalised values, so the highest phi is
    the smallest ``sum_j w_j h_j``. Weights are normalised by their sum, as in
    ``flows``; the tests check this against the pairwise definition.
    """
    return weighted_parts(range_vshape_parts(rows, len(weights)), weights, len(rows))


def weighted_parts(
    parts: Sequence[Sequence[float] | None], weights: Sequence[float], n: int
) -> list[float]:
    """phi from ``range_vshape_parts``, the weights normalised by their sum."""
    total = sum(weights)
    phi = [0.0] * n
    for weight, part in zip(weights, parts, strict=True):
        if weight and part is not None:
            share = weight / total
            for a, value in enumerate(part):
                phi[a] += share * value
    return phi


def range_vshape_parts(
    rows: Sequence[Sequence[float]], width: int
) -> list[list[float] | None]:
    """Each criterion's share of phi before its weight: ``(H_j - n h_j(a)) / (n - 1)``.

    None for a criterion whose range is 0 (it counts for nothing). Several
    weightings of one front (``robocloud.selection.choice.choices``) share them.
    """
    n = len(rows)
    parts: list[list[float] | None] = []
    if n < 2:
        return [None] * width  # one alternative (or none): every flow is 0
    for j in range(width):
        column = [row[j] for row in rows]
        lo, hi = min(column), max(column)
        if isclose(lo, hi):
            parts.append(None)
            continue
        h = [(x - lo) / (hi - lo) for x in column]
        total_h = sum(h)
        parts.append([(total_h - n * value) / (n - 1) for value in h])
    return parts


def flows(
    matrix: npt.ArrayLike,
    criteria: Sequence[Criterion],
    *,
    block_rows: int | None = None,
    fast: bool = True,
) -> Flows:
    """phi+, phi- and phi of each row of ``matrix`` (alternatives x criteria).

    ``block_rows`` bounds the rows of pi held at once (by default about a
    million table entries); ``fast=False`` takes the pairwise path even when
    every criterion is usual, so the two can be checked against each other.
    """
    x, w = _prepare(matrix, [c.weight for c in criteria], [c.minimize for c in criteria])
    n = x.shape[0]
    if fast and all(c.preference == "usual" for c in criteria):
        return _usual_flows(x, w)
    rows = block_rows or max(1, _BLOCK_ELEMENTS // max(n, 1))
    thresholds = [_threshold(x[:, j]) for j in range(x.shape[1])]
    positive = np.zeros(n)
    negative = np.zeros(n)
    for start in range(0, n, rows):
        stop = min(start + rows, n)
        pi = np.zeros((stop - start, n))  # pi(a, b) for a in the block
        for j, criterion in enumerate(criteria):
            if criterion.preference == "usual":
                pi += w[j] * (x[None, :, j] < thresholds[j][start:stop, None])
            else:
                d = x[start:stop, j, None] - x[None, :, j]
                pi += w[j] * _preference(criterion, d)
        positive[start:stop] = pi.sum(axis=1)
        negative += pi.sum(axis=0)
    return _scaled(positive, negative, n)


def net_flows(matrix: npt.ArrayLike, criteria: Sequence[Criterion]) -> FloatArray:
    """phi of each row of ``matrix``; the score Algorithm 3 ranks by."""
    return flows(matrix, criteria).net


def rank_order(ids: Sequence[str], phi: npt.ArrayLike) -> list[int]:
    """Indices by phi descending, ties (equal to 9 decimals) by id ascending."""
    scores = np.round(np.asarray(phi, dtype=np.float64), 9)
    if len(ids) != scores.shape[0]:
        raise ValueError("one phi per id is needed")
    if not ids:
        return []
    order: list[int] = np.lexsort((np.asarray(ids, dtype=str), -scores)).tolist()
    return order
