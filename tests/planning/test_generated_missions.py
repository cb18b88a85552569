"""Generated instances (the dataset's distributions, larger sizes): every plan is valid.

Instances are drawn as the MRTA-Benchmark dataset's are (Jakob Bichler, TU Delft,
DOI 10.4121/10e28ee0-9ad9-450d-8be7-6e6a91f2931f, CC BY 4.0).
"""

from __future__ import annotations

import pytest

from robocloud.planning.bounds import lower_bound
from robocloud.planning.construction import construct
from robocloud.planning.generate import generate
from robocloud.planning.greedy import greedy
from robocloud.planning.mrta import read_instance, solution
from robocloud.planning.solve import solve_all
from robocloud.planning.validate import check_mrta

SIZES = [(8, 3, 5), (15, 5, 6), (30, 10, 7)]


@pytest.mark.parametrize(("tasks", "robots", "seed"), SIZES)
def test_construction_and_greedy_plans_are_valid_and_above_the_bound(
    tasks: int, robots: int, seed: int
) -> None:
    instance = generate(tasks, robots, seed)
    problem = read_instance(instance)
    bound = lower_bound(problem)
    for schedule in (construct(problem), construct(problem, seed=3), greedy(problem)):
        assert schedule is not None
        assert check_mrta(instance, solution(problem, schedule)) == []
        assert schedule.makespan >= bound


def test_the_planner_improves_on_its_construction_and_stays_valid() -> None:
    instances = [generate(tasks, robots, seed) for tasks, robots, seed in SIZES]
    problems = [read_instance(i) for i in instances]
    plans = solve_all(problems, time_limit=3.0, seed=0)
    for instance, problem, plan in zip(instances, problems, plans, strict=True):
        assert plan.schedule is not None
        assert check_mrta(instance, solution(problem, plan.schedule)) == []
        first = construct(problem)
        assert first is not None
        assert plan.schedule.makespan <= first.makespan + 1e-6
        assert plan.lower_bound is not None
        assert plan.lower_bound <= plan.schedule.makespan + 1e-6
        assert plan.gap is not None and 0.0 <= plan.gap < 1.0
    assert [p.method for p in plans] == ["exact", "anytime", "anytime"]
