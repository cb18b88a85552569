"""The final choice (docs/model.md, "The choice"): V-shape PROMETHEE II over the front.

A worked example (docs/model.md's, by hand), a table of small fronts, random
fronts against the pairwise definition of phi, and the operator's kind of
front (issue 26), where the usual criterion gave every member the same flow.
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robocloud.domain import Coalition
from robocloud.domain.numeric import isclose, tolerance
from robocloud.errors import InvalidInput
from robocloud.selection.choice import (
    CHOICE_WEIGHTS,
    choice_flows,
    choices,
    choose,
    choose_index,
)
from robocloud.selection.promethee import Criterion, flows


def member(name: str, time: float, cost: float, size: int) -> Coalition:
    return Coalition(robots=tuple(f"{name}-{i}" for i in range(size)), time=time, cost=cost)


# docs/model.md's worked example: three coalitions of three robots, each faster and dearer.
A = member("a", 300.0, 210.0, 3)
B = member("b", 600.0, 150.0, 3)
C = member("c", 1200.0, 120.0, 3)
WORKED = [A, B, C]
# phi by hand (docs/model.md): exact fractions.
WORKED_PHI = {
    "balanced": (Fraction(-1, 18), Fraction(1, 9), Fraction(-1, 18)),
    "time": (Fraction(7, 30), Fraction(2, 15), Fraction(-11, 30)),
    "cost": (Fraction(-11, 30), Fraction(2, 15), Fraction(7, 30)),
}

FAST = member("fast", 10.0, 90.0, 3)
CHEAP = member("cheap", 90.0, 10.0, 3)
SMALL = member("small", 50.0, 50.0, 2)
# Two-member fronts: the V-shape with p = the range is the usual criterion there.
QUICK = member("quick", 10.0, 9.0, 2)
SLOW = member("slow", 80.0, 1.0, 2)
FEW = member("few", 80.0, 20.0, 1)
MANY = member("many", 20.0, 20.0, 3)


def direct_phi(front: list[Coalition], weights: tuple[float, float, float]) -> list[float]:
    """phi from its definition: every pair, P_j(a, b) = (g_j(b) - g_j(a)) / p_j when positive."""
    rows = [(c.time, c.cost, float(c.size)) for c in front]
    n = len(rows)
    if n == 1:
        return [0.0]
    total = sum(weights)
    ranges = []
    for j in range(3):
        lo, hi = min(r[j] for r in rows), max(r[j] for r in rows)
        ranges.append(None if isclose(lo, hi) else hi - lo)

    def pi(a: int, b: int) -> float:
        out = 0.0
        for j, p in enumerate(ranges):
            if p is not None:
                out += weights[j] / total * max(0.0, min(1.0, (rows[b][j] - rows[a][j]) / p))
        return out

    return [
        sum(pi(a, b) - pi(b, a) for b in range(n) if b != a) / (n - 1) for a in range(n)
    ]


def test_the_worked_example_by_hand() -> None:
    for priority, expected in WORKED_PHI.items():
        got = choice_flows(WORKED, priority)
        assert got == pytest.approx([float(f) for f in expected], abs=1e-12), priority
    assert choose(WORKED, "balanced") == B  # the interior member
    assert choose(WORKED, "time") == A
    assert choose(WORKED, "cost") == C
    assert choices(WORKED) == {"balanced": 1, "time": 0, "cost": 2}


def test_time_is_faster_and_cost_cheaper_than_balanced() -> None:
    balanced, time, cost = (choose(WORKED, p) for p in ("balanced", "time", "cost"))
    assert balanced is not None and time is not None and cost is not None
    assert time.time < balanced.time
    assert cost.cost < balanced.cost


def test_the_usual_criterion_would_have_tied_the_worked_example() -> None:
    """Why the rule changed: counts alone give every member of such a front phi = 0."""
    criteria = [Criterion(1 / 3), Criterion(1 / 3), Criterion(1 / 3)]
    rows = [(c.time, c.cost, float(c.size)) for c in WORKED]
    assert flows(rows, criteria).net.tolist() == [0.0, 0.0, 0.0]


@pytest.mark.parametrize(
    ("front", "balanced", "time", "cost"),
    [
        # Ranges 80, 80, 1: h(fast) = (0, 1, 1), h(cheap) = (1, 0, 1), h(small) = (.5, .5, 0).
        # time: fast and small tie at 0.4 -> the smaller cost, small; cost: cheap and
        # small tie at 0.4 -> cheap.
        ([FAST, CHEAP, SMALL], SMALL, SMALL, CHEAP),
        ([FAST, CHEAP], CHEAP, FAST, CHEAP),
        ([QUICK, SLOW], SLOW, QUICK, SLOW),
        # C has range 0 and counts for nothing; T against N: cost ties -> the tie rule.
        ([FEW, MANY], MANY, MANY, MANY),
        ([SMALL], SMALL, SMALL, SMALL),
    ],
)
def test_each_priority_picks_its_coalition(
    front: list[Coalition], balanced: Coalition, time: Coalition, cost: Coalition
) -> None:
    assert choose(front, "balanced") == balanced
    assert choose(front, "time") == time
    assert choose(front, "cost") == cost
    # The thesis's equal weights are the default.
    assert choose(front) == balanced
    assert choices(front) == {
        p: front.index(c) for p, c in (("balanced", balanced), ("time", time), ("cost", cost))
    }


def test_the_weights_are_those_docs_model_md_states() -> None:
    """The code and the contract say the same: the weights table of docs/model.md's choice."""
    from fractions import Fraction
    from pathlib import Path

    text = (Path(__file__).parents[2] / "docs" / "model.md").read_text(encoding="utf-8")
    choice = text[text.index("## The choice"):]
    documented = {}
    for line in choice.splitlines():
        cells = [c.strip().strip("`") for c in line.strip().strip("|").split("|")]
        if len(cells) == 4 and cells[0] in CHOICE_WEIGHTS:
            documented[cells[0]] = tuple(float(Fraction(c)) for c in cells[1:])
        if len(documented) == len(CHOICE_WEIGHTS):
            break
    assert set(documented) == set(CHOICE_WEIGHTS)
    for priority, weights in CHOICE_WEIGHTS.items():
        assert documented[priority] == pytest.approx(weights), priority


def test_ties_fall_to_cost_then_time_then_size_then_ids() -> None:
    a = Coalition(robots=("b",), time=5.0, cost=5.0)
    b = Coalition(robots=("a",), time=5.0, cost=5.0)
    assert choose([a, b], "time") == b


def test_empty_front_and_unknown_priority() -> None:
    assert choose([], "time") is None
    assert choices([]) is None
    with pytest.raises(InvalidInput, match="priority"):
        choose([FAST], "urgent")


@pytest.mark.parametrize("n", [3, 5, 9, 25, 60])
def test_balanced_picks_an_interior_member_of_a_convex_trade_off(n: int) -> None:
    """The operator's front (issue 26): one size, each member faster and dearer, convex.

    Points on the quarter circle (T, C) = (1 - cos u, 1 - sin u), scaled: any
    convex trade-off. The usual criterion tied them all, and the tie rule
    took the cheapest end.
    """
    angles = np.linspace(0.0, math.pi / 2, n)
    front = [
        member(f"m{i:02d}", 240.0 + 900.0 * (1 - math.cos(u)), 120.0 + 95.0 * (1 - math.sin(u)), 4)
        for i, u in enumerate(angles)
    ]
    index = choices(front)
    assert index is not None
    assert 0 < index["balanced"] < n - 1
    assert front[index["time"]].time < front[index["balanced"]].time
    assert front[index["cost"]].cost < front[index["balanced"]].cost


finite = st.floats(0.0, 1e6, allow_nan=False, allow_infinity=False)
coalitions = st.lists(
    st.builds(
        lambda i, t, c, n: member(f"r{i}", t, c, n),
        st.integers(0, 10**6),
        # Grid values with nudges around the tolerance, and free floats.
        st.one_of(st.integers(1, 6).map(lambda k: 50.0 * k), finite),
        st.one_of(st.integers(1, 6).map(lambda k: 3.0 * k + 4e-7), finite),
        st.integers(1, 4),
    ),
    min_size=1,
    max_size=40,
)


@settings(max_examples=300, deadline=None)
@given(coalitions, st.sampled_from(sorted(CHOICE_WEIGHTS)))
def test_random_fronts_against_the_definition(front: list[Coalition], priority: str) -> None:
    weights = CHOICE_WEIGHTS[priority]
    expected = direct_phi(front, weights)
    got = choice_flows(front, priority)
    assert got == pytest.approx(expected, abs=1e-9)
    # The choice: highest phi, ties (under the tolerance) by C, T, N, ids. A
    # member within 1e-9 of the tie's edge may fall either side.
    best = max(expected)
    chosen = choose(front, priority)
    assert chosen is not None
    at = front.index(chosen)
    assert expected[at] >= best - tolerance(best, expected[at]) - 1e-9
    surely_tied = [
        c for c, f in zip(front, expected, strict=True) if best - f <= tolerance(best, f) - 1e-9
    ]
    key = (chosen.cost, chosen.time, chosen.size, chosen.robots)
    assert all(key <= (c.cost, c.time, c.size, c.robots) for c in surely_tied)
    # The API's choices (one scaling for the three priorities) agree.
    every = choices(front)
    assert every is not None and every[priority] == choose_index(front, priority)


@settings(max_examples=100, deadline=None)
@given(coalitions)
def test_the_flows_are_the_general_vshape_path(front: list[Coalition]) -> None:
    """promethee.flows with V-shape criteria, p = the range: the same numbers."""
    rows = np.array([[c.time, c.cost, float(c.size)] for c in front])
    for priority, weights in CHOICE_WEIGHTS.items():
        criteria = [
            Criterion(w, True, "vshape", p=float(np.ptp(rows[:, j])))
            if not isclose(float(rows[:, j].min()), float(rows[:, j].max()))
            else Criterion(0.0)
            for j, w in enumerate(weights)
        ]
        kept = sum(c.weight for c in criteria)
        if kept == 0 or len(front) == 1:
            assert choice_flows(front, priority) == [0.0] * len(front)
            continue
        # flows normalises the weights it is given: scale back to the priority's.
        general = flows(rows, criteria).net * kept / sum(weights)
        assert choice_flows(front, priority) == pytest.approx(general.tolist(), abs=1e-9)
