"""Floating point equality as MODEL.md fixes it.

Two values are equal when they differ by at most 1e-9 relative or 1e-6
absolute. Every comparison of times, costs and flows goes through here so the
exact optimizer, MOPSO, the brute-force tests and the final choice agree on
what a tie is.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

REL_TOL = 1e-9
ABS_TOL = 1e-6


def margin(a: float) -> float:
    """The tolerance of one value: how far past ``a`` a value still counts as ``a``."""
    return max(ABS_TOL, REL_TOL * abs(a))


def margin_array(a: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """``margin`` of each value."""
    return np.asarray(np.maximum(ABS_TOL, REL_TOL * np.abs(a)))


def tolerance(a: float, b: float) -> float:
    """The largest difference at which ``a`` and ``b`` still count as equal."""
    return max(ABS_TOL, REL_TOL * max(abs(a), abs(b)))


def isclose(a: float, b: float) -> bool:
    return abs(a - b) <= tolerance(a, b)


def less(a: float, b: float) -> bool:
    """``a < b`` and not equal under the tolerance."""
    return a < b and not isclose(a, b)


def less_equal(a: float, b: float) -> bool:
    return a < b or isclose(a, b)


def isclose_array(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> npt.NDArray[np.bool_]:
    tol = np.maximum(ABS_TOL, REL_TOL * np.maximum(np.abs(a), np.abs(b)))
    return np.asarray(np.abs(a - b) <= tol)


def less_array(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> npt.NDArray[np.bool_]:
    return np.asarray((a < b) & ~isclose_array(a, b))
