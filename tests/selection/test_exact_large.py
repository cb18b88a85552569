"""The exact optimizer against a MILP reference (HiGHS) on coalitions of 20 to 60 robots."""

from __future__ import annotations

import numpy as np
import pytest
from large_instances import fleet_problem, mixed_problem
from milp_reference import milp_front

from robocloud.selection.exact import exact_front, exact_search
from robocloud.selection.problem import CoalitionProblem


def non_dominated(points: set[tuple[float, float, int]]) -> list[tuple[float, float, int]]:
    def better(a: tuple[float, float, int], b: tuple[float, float, int]) -> bool:
        no_worse = a[0] <= b[0] + 1e-6 and a[1] <= b[1] + 1e-6 and a[2] <= b[2]
        return no_worse and (a[0] < b[0] - 1e-6 or a[1] < b[1] - 1e-6 or a[2] < b[2])

    return sorted(p for p in points if not any(better(q, p) for q in points))


def check_against_reference(problem: CoalitionProblem) -> None:
    front = exact_front(problem)
    reference = non_dominated(milp_front(problem))
    assert front, "the instances are feasible"
    assert len(front) == len(reference)
    for coalition, (time, cost, size) in zip(front, reference, strict=True):
        assert coalition.time == pytest.approx(time, abs=1e-6)
        assert coalition.cost == pytest.approx(cost, abs=1e-6)
        assert coalition.size == size
        row = np.isin(np.array(problem.ids), coalition.robots)[None, :]
        assert problem.feasible(row)[0]


@pytest.mark.parametrize(
    ("seed", "robots", "counts", "max_time"),
    [(1, 90, (10, 10, 4, 4), 250.0), (3, 220, (30, 30, 8, 8), 260.0)],
    ids=["20-robots", "60-robots"],
)
def test_fleet_front_equals_the_milp_reference(
    seed: int, robots: int, counts: tuple[int, int, int, int], max_time: float
) -> None:
    problem = fleet_problem(seed, robots, counts, max_time)
    check_against_reference(problem)
    assert {c.size for c in exact_front(problem)} == {counts[0] + counts[1]}


@pytest.mark.slow
def test_40_robot_fleet_front_equals_the_milp_reference() -> None:
    check_against_reference(fleet_problem(2, 150, (20, 20, 6, 6), 250.0))


@pytest.mark.slow
@pytest.mark.parametrize("seed", [5, 6, 8])
def test_front_trading_size_equals_the_milp_reference(seed: int) -> None:
    problem = mixed_problem(seed, 70, (14, 10, 8))
    check_against_reference(problem)
    assert len({c.size for c in exact_front(problem)}) > 1


def test_sizes_trade_against_cost_and_time() -> None:
    # A front of 14 to 20 robots: several size limits add points.
    problem = mixed_problem(5, 70, (14, 10, 8))
    outcome = exact_search(problem)
    assert outcome.complete and outcome.bound is not None and outcome.bound.exact
    sizes = {c.size for c in outcome.front}
    assert min(sizes) >= 14 and len(sizes) >= 3
