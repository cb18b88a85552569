"""PROMETHEE II (thesis Algorithm 3) against pymcdm, a textbook formula and itself."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymcdm.methods import PROMETHEE_II

from robocloud.errors import InvalidInput
from robocloud.selection.problem import CoalitionProblem
from robocloud.selection.promethee import (
    Criterion,
    Preference,
    flows,
    net_flows,
    rank_order,
    usual_net_flows,
)
from robocloud.selection.ranking import rank_candidates

SHARED: tuple[Preference, ...] = (
    "usual",
    "ushape",
    "vshape",
    "level",
    "vshape_2",
)  # offered by pymcdm too


def test_pymcdm_documented_example() -> None:
    matrix = [[4, 3, 2], [3, 2, 4], [5, 1, 3]]
    criteria = [Criterion(w, minimize=False) for w in (0.5, 0.3, 0.2)]
    np.testing.assert_allclose(net_flows(matrix, criteria), [0.1, -0.3, 0.2], atol=1e-12)


def _random_case(
    seed: int, preference: Preference
) -> tuple[np.ndarray, list[Criterion], PROMETHEE_II, np.ndarray, np.ndarray]:
    """A random problem, ours and pymcdm's; integer seeds hit d == q and d == p exactly."""
    rng = np.random.default_rng(seed)
    n, m = int(rng.integers(2, 31)), int(rng.integers(2, 6))
    integral = seed % 2 == 0
    if integral:
        matrix = rng.integers(0, 12, (n, m)).astype(float)
        q = rng.integers(0, 4, m).astype(float)
        p = q + rng.integers(1, 5, m).astype(float)
    else:
        matrix = rng.random((n, m)) * 100
        q = rng.random(m) * 20
        p = q + 1 + rng.random(m) * 30
    weights = rng.random(m) + 0.01
    types = rng.choice([-1, 1], m)
    if preference == "vshape":
        q = np.zeros(m)
    criteria = [
        Criterion(float(weights[j]), bool(types[j] == -1), preference, float(q[j]), float(p[j]))
        for j in range(m)
    ]
    thresholds = {
        "usual": {},
        "ushape": {"q": q},
        "vshape": {"p": p},
        "level": {"q": q, "p": p},
        "vshape_2": {"q": q, "p": p},
    }[preference]
    return matrix, criteria, PROMETHEE_II(preference, **thresholds), weights / weights.sum(), types


@pytest.mark.parametrize("preference", SHARED)
@pytest.mark.parametrize("seed", range(40))
def test_agrees_with_pymcdm(preference: Preference, seed: int) -> None:
    matrix, criteria, body, weights, types = _random_case(seed, preference)
    # _method gives phi+ and phi- besides phi; __call__ only the last.
    *_, plus, minus, net = body._method(matrix, weights, types)
    ours = flows(matrix, criteria, block_rows=1 + seed % 7, fast=False)
    np.testing.assert_allclose(ours.positive, plus, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ours.negative, minus, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ours.net, net, rtol=0, atol=1e-9)
    np.testing.assert_allclose(net_flows(matrix, criteria), net, rtol=0, atol=1e-9)


@pytest.mark.parametrize("seed", range(30))
def test_fast_usual_path_equals_blocked_path(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n, m = int(rng.integers(1, 60)), int(rng.integers(1, 5))
    matrix = rng.integers(0, 4, (n, m)).astype(float)  # many exact ties
    weights = rng.random(m) + 0.01
    minimize = rng.random(m) < 0.5
    criteria = [Criterion(float(w), bool(mi)) for w, mi in zip(weights, minimize, strict=True)]
    fast = flows(matrix, criteria)
    blocked = flows(matrix, criteria, block_rows=int(rng.integers(1, 9)), fast=False)
    for got, want in zip(fast, blocked, strict=True):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    np.testing.assert_allclose(usual_net_flows(matrix, weights, minimize), fast.net, atol=1e-12)


@pytest.mark.parametrize("scale, noise", [(1.0, 4e-7), (1e7, 4e-3)])
@pytest.mark.parametrize("seed", range(10))
def test_ties_within_tolerance_are_no_preference(scale: float, noise: float, seed: int) -> None:
    """Values 1 apart (times scale) and jittered well inside docs/model.md's tolerance
    (1e-6 absolute; 1e-9 * 1e7 = 1e-2 relative) rank like the exact integers."""
    rng = np.random.default_rng(seed)
    exact = rng.integers(0, 5, (40, 3)) * 100.0 + scale
    jittered = exact + rng.uniform(-noise, noise, exact.shape)
    criteria = [Criterion(1.0), Criterion(2.0, minimize=False), Criterion(0.5)]
    want = net_flows(exact, criteria)
    np.testing.assert_allclose(net_flows(jittered, criteria), want, rtol=0, atol=1e-12)
    blocked = flows(jittered, criteria, block_rows=6, fast=False).net
    np.testing.assert_allclose(blocked, want, rtol=0, atol=1e-12)


def test_tolerance_boundary() -> None:
    criteria = [Criterion(1.0)]
    assert net_flows([[0.0], [5e-7]], criteria).tolist() == [0.0, 0.0]
    assert net_flows([[0.0], [2e-6]], criteria).tolist() == [1.0, -1.0]


@pytest.mark.parametrize("seed", range(10))
def test_gaussian_matches_textbook_formula(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n, m = 12, 3
    matrix = rng.normal(0, 5, (n, m))
    s = rng.random(m) * 4 + 0.5
    weights = rng.random(m) + 0.1
    minimize = rng.random(m) < 0.5
    criteria = [
        Criterion(float(weights[j]), bool(minimize[j]), "gaussian", s=float(s[j])) for j in range(m)
    ]

    def pref(j: int, a: int, b: int) -> float:
        d = float(matrix[a, j] - matrix[b, j]) * (-1 if minimize[j] else 1)
        return 1 - math.exp(-(d**2) / (2 * float(s[j]) ** 2)) if d > 0 else 0.0

    def pi(a: int, b: int) -> float:
        return sum(float(weights[j]) * pref(j, a, b) for j in range(m)) / float(weights.sum())

    want = [sum(pi(a, b) - pi(b, a) for b in range(n) if b != a) / (n - 1) for a in range(n)]
    np.testing.assert_allclose(net_flows(matrix, criteria), want, rtol=0, atol=1e-12)


def _problem(ids: tuple[str, ...], time: list[float], cost: list[float]) -> CoalitionProblem:
    n = len(ids)
    return CoalitionProblem(
        ids=ids,
        time=np.array(time),
        cost=np.array(cost),
        uses=np.ones((n, 1), dtype=bool),
        capabilities=("camera",),
        need=np.array([1], dtype=np.int64),
        max_robots=n,
        max_cost=1e9,
        max_time=1e9,
    )


def test_priority_decides_between_fast_and_cheap() -> None:
    problem = _problem(("fast", "cheap"), time=[10.0, 20.0], cost=[100.0, 50.0])
    order, phi = rank_candidates(problem, "time")
    assert order.tolist() == [0, 1]
    np.testing.assert_allclose(phi, [0.5, -0.5])
    order, _ = rank_candidates(problem, "cost")
    assert order.tolist() == [1, 0]
    order, phi = rank_candidates(problem, "balanced")
    assert order.tolist() == [1, 0]  # a tie: "cheap" < "fast"
    np.testing.assert_allclose(phi, [0.0, 0.0])


def test_ties_are_broken_by_id() -> None:
    problem = _problem(("r-3", "r-1", "r-2", "r-0"), [5.0, 5.0, 5.0, 1.0], [2.0, 2.0, 2.0, 9.0])
    order, _ = rank_candidates(problem, "cost")
    assert order.dtype == np.int64
    assert order.tolist() == [1, 2, 0, 3]  # r-1, r-2, r-3 tie; r-0 is dearest
    order, _ = rank_candidates(problem, "balanced")
    assert order.tolist() == [3, 1, 2, 0]  # all four tie
    assert rank_order(["c", "b", "a"], [0.5, 0.5 + 1e-12, 0.7]) == [2, 1, 0]


def test_unknown_priority_is_invalid_input() -> None:
    with pytest.raises(InvalidInput):
        rank_candidates(_problem(("a",), [1.0], [1.0]), "speed")


def test_single_alternative_has_zero_flow() -> None:
    assert net_flows([[3.0, 4.0]], [Criterion(1.0), Criterion(1.0, False, "vshape", p=1)]) == [0]


@st.composite
def _problems(draw: st.DrawFn) -> tuple[np.ndarray, list[Criterion]]:
    n = draw(st.integers(1, 15))
    m = draw(st.integers(1, 4))
    value = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)
    matrix = np.array([[draw(value) for _ in range(m)] for _ in range(n)]).reshape(n, m)
    criteria = []
    for _ in range(m):
        kind: Preference = draw(st.sampled_from((*SHARED, "gaussian")))
        q = draw(st.floats(0, 100))
        p = q + draw(st.floats(0.01, 100))
        weight = draw(st.floats(0.01, 10))
        criteria.append(Criterion(weight, draw(st.booleans()), kind, q, p, s=p))
    return matrix, criteria


@settings(max_examples=200, deadline=None)
@given(_problems())
def test_net_flows_sum_to_zero_and_stay_in_range(case: tuple[np.ndarray, list[Criterion]]) -> None:
    matrix, criteria = case
    phi = net_flows(matrix, criteria)
    assert abs(phi.sum()) <= 1e-9
    assert np.all((phi >= -1 - 1e-12) & (phi <= 1 + 1e-12))
