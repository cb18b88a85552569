"""The final choice follows the task's priority (MODEL.md): a table of small fronts."""

from __future__ import annotations

import pytest

from robocloud.domain import Coalition
from robocloud.errors import InvalidInput
from robocloud.selection.choice import CHOICE_WEIGHTS, choose


def member(name: str, time: float, cost: float, size: int) -> Coalition:
    return Coalition(robots=tuple(f"{name}-{i}" for i in range(size)), time=time, cost=cost)


FAST = member("fast", 10.0, 90.0, 3)
CHEAP = member("cheap", 90.0, 10.0, 3)
SMALL = member("small", 50.0, 50.0, 2)
# Two-member fronts where balanced weights tie and the tie rule decides.
QUICK = member("quick", 10.0, 9.0, 2)
SLOW = member("slow", 80.0, 1.0, 2)
FEW = member("few", 80.0, 20.0, 1)
MANY = member("many", 20.0, 20.0, 3)


@pytest.mark.parametrize(
    ("front", "balanced", "time", "cost"),
    [
        # Worked by hand: phi(small) = 1/3 balanced; phi(fast) = 0.3 for time; cost mirrors it.
        ([FAST, CHEAP, SMALL], SMALL, FAST, CHEAP),
        ([QUICK, SLOW], SLOW, QUICK, SLOW),
        # T against N only: time picks the faster, cost (N weighs 0.2, T 0.2) ties -> the tie rule.
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


def test_weights_are_modelmd() -> None:
    assert CHOICE_WEIGHTS == {
        "balanced": (1 / 3, 1 / 3, 1 / 3),
        "time": (0.6, 0.2, 0.2),
        "cost": (0.2, 0.6, 0.2),
    }


def test_ties_fall_to_cost_then_time_then_size_then_ids() -> None:
    a = Coalition(robots=("b",), time=5.0, cost=5.0)
    b = Coalition(robots=("a",), time=5.0, cost=5.0)
    assert choose([a, b], "time") == b


def test_empty_front_and_unknown_priority() -> None:
    assert choose([], "time") is None
    with pytest.raises(InvalidInput, match="priority"):
        choose([FAST], "urgent")
