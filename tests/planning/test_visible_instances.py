"""The 12 visible MRTA-Benchmark instances: the planner finds the proven optimum.

Dataset: MRTA-Benchmark by Jakob Bichler (TU Delft), DOI
10.4121/10e28ee0-9ad9-450d-8be7-6e6a91f2931f, CC BY 4.0 (see mrta_dataset.py).
Solve times are measured by benchmarks/missions.py, never asserted here.
"""

from __future__ import annotations

from typing import Any

import pytest
from mrta_dataset import visible

from robocloud.planning.greedy import greedy
from robocloud.planning.mrta import read_instance, solution
from robocloud.planning.plan import Plan
from robocloud.planning.solve import solve_all
from robocloud.planning.validate import TOLERANCE, check_mrta

INSTANCES = visible()
IDS = [row[0] for row in INSTANCES]


@pytest.fixture(scope="module")
def plans() -> dict[str, Plan]:
    problems = [read_instance(instance) for _, instance, _, _ in INSTANCES]
    # One child process for all twelve; a generous limit, as a loaded CI machine
    # may be slow (the benchmark reports the times).
    return dict(zip(IDS, solve_all(problems, time_limit=20.0, seed=0), strict=True))


@pytest.mark.parametrize("index", range(len(INSTANCES)), ids=IDS)
def test_the_plan_is_valid_and_optimal(index: int, plans: dict[str, Plan]) -> None:
    name, instance, reference, optimum = INSTANCES[index]
    plan = plans[name]
    assert plan.schedule is not None
    output: dict[str, Any] = solution(read_instance(instance), plan.schedule)
    assert check_mrta(instance, output) == []
    assert output["makespan"] == pytest.approx(optimum, abs=TOLERANCE)
    assert plan.optimal
    assert plan.lower_bound is not None
    assert optimum - TOLERANCE <= plan.lower_bound + TOLERANCE
    assert plan.lower_bound <= output["makespan"]
    assert plan.gap is not None and plan.gap < 1e-5
    # The dataset's shape, field by field.
    assert set(output) == set(reference)
    assert set(output["robot_schedules"]) == set(reference["robot_schedules"])


@pytest.mark.parametrize("index", range(len(INSTANCES)), ids=IDS)
def test_the_validator_accepts_the_datasets_own_schedule(index: int) -> None:
    _, instance, reference, _ = INSTANCES[index]
    assert check_mrta(instance, reference) == []


@pytest.mark.parametrize("index", range(len(INSTANCES)), ids=IDS)
def test_the_greedy_baseline_is_valid_and_no_better_than_optimal(index: int) -> None:
    _, instance, _, optimum = INSTANCES[index]
    problem = read_instance(instance)
    schedule = greedy(problem)
    assert schedule is not None
    output = solution(problem, schedule)
    assert check_mrta(instance, output) == []
    assert output["makespan"] >= optimum - TOLERANCE


def test_the_same_seed_gives_the_same_plan() -> None:
    problems = [read_instance(INSTANCES[0][1]), read_instance(INSTANCES[0][1])]
    first, second = solve_all(problems, time_limit=20.0, seed=3)
    assert first.schedule == second.schedule
