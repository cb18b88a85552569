"""The time budget: a cut search returns a feasible front, says so, and bounds its distance."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from large_instances import fleet_problem, mixed_problem

from robocloud.domain import Coalition, Robot, Task
from robocloud.errors import InvalidInput
from robocloud.selection.budget import Deadline
from robocloud.selection.exact import exact_search
from robocloud.selection.pipeline import select
from robocloud.selection.problem import CoalitionProblem


class AfterChecks(Deadline):
    """A deadline that passes after a number of checks: cuts at a chosen step, not by luck."""

    def __init__(self, checks: int) -> None:
        super().__init__(None, 1.0)
        object.__setattr__(self, "left", checks)

    def expired(self) -> bool:
        left = self.left  # type: ignore[attr-defined]
        object.__setattr__(self, "left", left - 1)
        return bool(left <= 0)

    def remaining(self) -> float:
        return 0.0 if self.left <= 0 else math.inf  # type: ignore[attr-defined]


@functools.cache
def problem_of(kind: str) -> CoalitionProblem:
    if kind == "fleet":
        return fleet_problem(3, 220, (30, 30, 8, 8), 260.0)
    return mixed_problem(5, 70, (14, 10, 8))


@functools.cache
def truth_of(kind: str) -> tuple[list[Coalition], int]:
    """The true front, and how many times a whole search looks at its deadline."""
    counter = AfterChecks(10**9)
    front = exact_search(problem_of(kind), deadline=counter).front
    return front, int(10**9 - counter.left)  # type: ignore[attr-defined]


def matched(kind: str, share: float) -> None:
    """Cut a share of the way through; check feasibility and the certificate
    against the true front."""
    problem = problem_of(kind)
    truth, total = truth_of(kind)
    checks = max(1, int(share * total))
    outcome = exact_search(problem, deadline=AfterChecks(checks))
    assert not outcome.complete
    for coalition in outcome.front:
        row = np.isin(np.array(problem.ids), coalition.robots)[None, :]
        assert problem.feasible(row)[0]
    if not outcome.front:
        assert outcome.bound is None
        return
    bound = outcome.bound
    assert bound is not None
    for point in truth:
        assert any(
            found.time <= point.time + bound.time + 1e-6
            and found.cost <= point.cost + bound.cost + 1e-6
            and found.size <= point.size + bound.size
            for found in outcome.front
        ), (point, bound)


@pytest.mark.parametrize("share", [0.0, 0.05, 0.3, 0.6, 0.95])
def test_a_cut_sweep_keeps_a_feasible_front_and_a_true_bound(share: float) -> None:
    matched("fleet", share)


@pytest.mark.parametrize("share", [0.1, 0.4, 0.7, 0.95])
def test_a_cut_in_a_later_size_sweep_is_bounded_too(share: float) -> None:
    # Sizes 14 to 20: the later sweeps (smaller size limits) are cut too.
    matched("mixed", share)


def test_the_bound_is_zero_and_complete_without_a_cut() -> None:
    outcome = exact_search(fleet_problem(1, 90, (10, 10, 4, 4), 250.0))
    assert outcome.complete and outcome.bound is not None and outcome.bound.exact


def test_a_bound_shrinks_as_the_sweep_goes_on() -> None:
    problem = problem_of("fleet")
    early = exact_search(problem, deadline=AfterChecks(3)).bound
    late = exact_search(problem, deadline=AfterChecks(25)).bound
    assert early is not None and late is not None
    assert late.time < early.time


def robots_and_task(budget_count: int = 30) -> tuple[list[Robot], Task]:
    rng = np.random.default_rng(11)
    robots = [
        Robot.model_validate(
            {
                "id": f"r-{i:03d}",
                "cloud": "cloud-a",
                "position": [float(rng.uniform(0, 300)), float(rng.uniform(0, 300))],
                "speed": 1.0,
                "battery": 90.0,
                "status": "idle",
                "travel_cost_per_m": 0.01,
                "capabilities": {
                    "grabber": {"kind": "actuating", "time": float(rng.uniform(10, 60)),
                                "cost": float(rng.uniform(1, 9))},
                },
            }
        )
        for i in range(200)
    ]
    task = Task.model_validate(
        {"location": [150.0, 150.0], "actuating": {"grabber": budget_count}, "max_robots": 60,
         "max_cost": 1e6, "max_time": 1e6}
    )
    return robots, task


def test_select_says_when_its_budget_ran_out() -> None:
    robots, task = robots_and_task()
    result = select(robots, task, budget_s=1e-9)
    assert not result.complete
    assert result.chosen is None and result.pareto == ()
    assert "time budget of 1e-09 s ran out" in (result.reason or "")
    data = result.to_json()
    assert data["complete"] is False and data["bound"] is None


def test_select_within_budget_is_complete_and_exact() -> None:
    robots, task = robots_and_task()
    result = select(robots, task, budget_s=30.0)
    assert result.complete and result.chosen is not None
    data = result.to_json()
    # docs/model.md's keys stay; the new ones are added.
    assert list(data)[:7] == ["candidates", "ranking", "pareto", "chosen", "reason",
                              "optimizer", "elapsed_ms"]
    assert data["bound"] == {"time": 0.0, "cost": 0.0, "size": 0}
    assert data["note"] is None


def test_mopso_stops_at_the_deadline_with_what_it_has() -> None:
    robots, task = robots_and_task(5)
    result = select(robots, task, "mopso", budget_s=1e-9)
    assert not result.complete
    assert result.bound is None


@pytest.mark.parametrize("budget", [0, -1.0, math.inf, math.nan, True, "2"])
def test_a_bad_budget_is_invalid_input(budget: object) -> None:
    robots, task = robots_and_task()
    with pytest.raises(InvalidInput, match="budget_s"):
        select(robots, task, budget_s=budget)  # type: ignore[arg-type]


def test_counts_whose_product_is_astronomical_stay_bounded() -> None:
    # 1,000 + 1,000 + 500 + 500: the old coverage table would have had about
    # 2.5e11 cells per size; the class-count search holds nothing of the kind.
    rng = np.random.default_rng(5)
    robots = 6000
    uses = np.zeros((robots, 4), dtype=bool)
    uses[np.arange(robots), rng.integers(0, 2, robots)] = True
    uses[:, 2:] = rng.random((robots, 2)) < 0.4
    problem = CoalitionProblem(
        ids=tuple(f"r-{i:05d}" for i in range(robots)),
        time=rng.uniform(10, 1000, robots),
        cost=rng.uniform(1, 20, robots),
        uses=uses,
        capabilities=("a", "b", "c", "d"),
        need=np.array([1000, 1000, 500, 500]),
        max_robots=100_000,
        max_cost=1e9,
        max_time=1e9,
    )
    outcome = exact_search(problem, deadline=Deadline.after(0.5))
    assert outcome.front
    for coalition in outcome.front[:5]:
        row = np.isin(np.array(problem.ids), coalition.robots)[None, :]
        assert problem.feasible(row)[0]
    assert outcome.complete or outcome.bound is not None
