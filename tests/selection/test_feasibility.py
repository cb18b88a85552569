"""Cheap infeasibility first: sound, immediate, and no optimizer runs."""

from __future__ import annotations

import numpy as np
import pytest
from brute_force import brute_force_front
from instances import random_problem

from robocloud.domain import Robot, Task
from robocloud.selection import pipeline
from robocloud.selection.feasibility import least_cost, quick_infeasibility
from robocloud.selection.pipeline import select

KINDS = {"light": "sensing", "sound": "sensing", "grabber": "actuating", "kicker": "actuating"}


def robot(i: int, caps: dict[str, tuple[float, float]]) -> Robot:
    return Robot.model_validate(
        {
            "id": f"r-{i:04d}", "cloud": "cloud-a", "position": [0.0, 0.0], "speed": 1.0,
            "battery": 90.0, "status": "idle", "travel_cost_per_m": 0.0,
            "capabilities": {n: {"kind": KINDS[n], "time": t, "cost": c}
                             for n, (t, c) in caps.items()},
        }
    )


def task(**kw: object) -> Task:
    data: dict[str, object] = {"location": [0.0, 0.0], "actuating": {"grabber": 2},
                               "max_robots": 5, "max_cost": 100.0, "max_time": 100.0}
    data.update(kw)
    return Task.model_validate(data)


@pytest.fixture
def no_optimizer(monkeypatch: pytest.MonkeyPatch) -> None:
    """Any optimisation (or pruning) in select now fails the test."""

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("an optimizer ran")

    for name in ("prune", "exact_search", "mopso_search", "build_pool", "seed_covers"):
        monkeypatch.setattr(pipeline, name, refuse)


GRABBERS = [robot(i, {"grabber": (10, 1)}) for i in range(50)]


@pytest.mark.usefixtures("no_optimizer")
@pytest.mark.parametrize(
    ("robots", "request_fields", "said"),
    [
        # The request: absurd counts against the robots that bring them.
        (GRABBERS, {"actuating": {"grabber": 1000}, "max_robots": 100_000},
         ["'grabber' needs 1,000 robots", "only 50 robots"]),
        (GRABBERS, {"actuating": {"grabber": 7}, "max_robots": 6},
         ["max_robots 6 cannot be met", "'grabber' alone needs 7 robots"]),
        ([robot(i, {"grabber": (500, 1)}) for i in range(5)], {},
         ["max_time 100 s cannot be met"]),
        # 3 lights and 3 grabbers, every robot brings one: at least 6 robots.
        ([robot(i, {"grabber": (10, 1)}) for i in range(5)]
         + [robot(10 + i, {"light": (10, 1)}) for i in range(5)],
         {"sensing": {"light": 3}, "actuating": {"grabber": 3}},
         ["max_robots 5 cannot be met", "at least 6 robots"]),
        (GRABBERS, {"max_cost": 1.5}, ["max_cost 1.5 cannot be met", "costs 2.00 or more"]),
    ],
    ids=["absurd-count", "count-above-max-robots", "max-time", "covering-bound", "cost-bound"],
)
def test_infeasible_requests_answer_without_optimising(
    robots: list[Robot], request_fields: dict[str, object], said: list[str]
) -> None:
    for optimizer in ("auto", "exact", "mopso"):
        result = select(robots, task(**request_fields), optimizer)  # type: ignore[arg-type]
        assert not result.searched and result.complete
        assert result.chosen is None and result.pareto == ()
        for words in said:
            assert words in (result.reason or ""), result.reason


def test_counts_summing_past_max_robots_can_still_be_met() -> None:
    # 3 lights + 3 grabbers > max_robots 4, yet 3 robots bring both: the
    # unsound "sum of counts" test would have refused this task.
    robots = [robot(i, {"grabber": (10, 1), "light": (10, 1)}) for i in range(3)]
    request = task(sensing={"light": 3}, actuating={"grabber": 3}, max_robots=4)
    problem = pipeline.CoalitionProblem.build(robots, request)
    assert quick_infeasibility(problem, request) is None
    result = select(robots, request)
    assert result.chosen is not None and result.chosen.size == 3


@pytest.mark.parametrize("seed", range(100))
def test_the_cheap_tests_are_sound(seed: int) -> None:
    """They never refuse a task that some coalition can serve; the cost bound is a bound."""
    rng = np.random.default_rng(seed)
    problem = random_problem(rng, int(rng.integers(1, 12)))
    front = brute_force_front(problem)
    if front:
        fitting = problem.time <= problem.max_time + 1e-6
        assert least_cost(problem, fitting) <= min(c.cost for c in front) + 1e-9
    names = {name: int(q) for name, q in zip(problem.capabilities, problem.need, strict=True)}
    request = Task.model_validate(
        {"location": [0.0, 0.0], "sensing": names, "max_robots": problem.max_robots,
         "max_cost": min(problem.max_cost, 1e12), "max_time": min(problem.max_time, 1e9)}
    )
    if front and problem.size:
        assert quick_infeasibility(problem, request) is None
