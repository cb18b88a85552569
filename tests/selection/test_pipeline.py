"""The whole pipeline over random fleets (hypothesis) and its reasons."""

import itertools

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from robocloud.domain import Robot, Task
from robocloud.selection.exact import exact_front
from robocloud.selection.filtering import filter_robots
from robocloud.selection.pareto import dominates
from robocloud.selection.pipeline import select, select_problem
from robocloud.selection.pool import build_pool
from robocloud.selection.problem import CoalitionProblem
from robocloud.selection.ranking import rank_candidates

CAPABILITIES = {
    "light": "sensing",
    "sound": "sensing",
    "grabber": "actuating",
    "kicker": "actuating",
}


@st.composite
def robots_and_task(draw: st.DrawFn) -> tuple[list[Robot], Task]:
    n = draw(st.integers(1, 9))
    robots = []
    for i in range(n):
        names = draw(st.sets(st.sampled_from(sorted(CAPABILITIES)), min_size=0, max_size=3))
        robots.append(
            Robot(
                id=f"r-{i}",
                cloud=draw(st.sampled_from(["cloud-a", "cloud-b"])),
                position=[draw(st.floats(0, 100)), draw(st.floats(0, 100))],
                speed=draw(st.floats(0.5, 3)),
                battery=draw(st.floats(0, 100)),
                status=draw(st.sampled_from(["idle", "idle", "idle", "busy", "offline"])),
                travel_cost_per_m=draw(st.floats(0, 0.2)),
                capabilities={
                    name: {
                        "kind": CAPABILITIES[name],
                        "time": draw(st.floats(0, 60)),
                        "cost": draw(st.floats(0, 10)),
                    }
                    for name in names
                },
            )
        )
    wanted = draw(st.sets(st.sampled_from(sorted(CAPABILITIES)), min_size=1, max_size=3))
    counts = {name: draw(st.integers(1, 2)) for name in wanted}
    task = Task(
        location=[50.0, 50.0],
        sensing={k: v for k, v in counts.items() if CAPABILITIES[k] == "sensing"},
        actuating={k: v for k, v in counts.items() if CAPABILITIES[k] == "actuating"},
        max_robots=draw(st.integers(1, 6)),
        max_cost=draw(st.floats(5, 60)),
        max_time=draw(st.floats(30, 200)),
        min_battery=draw(st.floats(0, 80)),
        priority=draw(st.sampled_from(["balanced", "time", "cost"])),
        execution=draw(st.sampled_from(["parallel", "sequential"])),
    )
    return robots, task


def feasible_subsets(problem: CoalitionProblem) -> list[tuple[int, ...]]:
    found = []
    for size in range(1, problem.size + 1):
        for subset in itertools.combinations(range(problem.size), size):
            row = np.zeros((1, problem.size), dtype=bool)
            row[0, list(subset)] = True
            if problem.feasible(row)[0]:
                found.append(subset)
    return found


@pytest.mark.slow  # seconds of work: in make test, not in make check
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(robots_and_task())
def test_select_invariants(case: tuple[list[Robot], Task]) -> None:
    robots, task = case
    candidates = filter_robots(robots, task)
    problem = CoalitionProblem.build(candidates, task)
    any_feasible = bool(feasible_subsets(problem))
    for optimizer in ("exact", "mopso"):
        result = select(robots, task, optimizer=optimizer, seed=3)
        assert result.optimizer == optimizer
        assert result.candidates == len(candidates)
        assert sorted(result.ranking) == sorted(r.id for r in candidates)
        assert (result.chosen is not None) == any_feasible
        assert (result.reason is None) == any_feasible
        for a, b in itertools.permutations(result.pareto, 2):
            assert not dominates(a, b)
        index = {robot_id: i for i, robot_id in enumerate(problem.ids)}
        for member in result.pareto:
            row = np.zeros((1, problem.size), dtype=bool)
            row[0, [index[r] for r in member.robots]] = True
            assert problem.feasible(row)[0]
        if result.chosen is not None:
            assert result.chosen in result.pareto
    # The pool never hides a feasible coalition.
    order, _ = rank_candidates(problem, task.priority)
    pool = build_pool(problem, order, 1)
    assert bool(exact_front(problem.subproblem(pool))) == any_feasible


def robot(i: int, caps: dict[str, tuple[float, float]], x: float = 0.0, **kw: object) -> Robot:
    data = {
        "id": f"r-{i}",
        "cloud": "cloud-a",
        "position": [x, 0.0],
        "speed": 1.0,
        "battery": 90.0,
        "status": "idle",
        "travel_cost_per_m": 0.0,
        "capabilities": {
            n: {"kind": CAPABILITIES[n], "time": t, "cost": c} for n, (t, c) in caps.items()
        },
    }
    data.update(kw)
    return Robot.model_validate(data)


def task(**kw: object) -> Task:
    data = {
        "location": [0.0, 0.0],
        "actuating": {"grabber": 2},
        "max_robots": 5,
        "max_cost": 100.0,
        "max_time": 100.0,
        "min_battery": 50.0,
    }
    data.update(kw)
    return Task.model_validate(data)


def test_reason_names_the_missing_capability() -> None:
    result = select([robot(1, {"grabber": (10, 1)})], task())
    assert result.chosen is None and result.pareto == ()
    assert "'grabber' needs 2 robots" in (result.reason or "")
    assert "only 1 robot" in (result.reason or "")


def test_reason_names_the_battery_filter() -> None:
    robots = [robot(i, {"grabber": (10, 1)}, battery=20.0) for i in range(3)]
    reason = select(robots, task()).reason or ""
    assert "battery at or above 50%" in reason


def test_reason_names_max_time_max_robots_and_max_cost() -> None:
    far = [robot(i, {"grabber": (10, 1)}, x=500.0) for i in range(3)]
    assert "max_time 100 s" in (select(far, task()).reason or "")
    near = [robot(i, {"grabber": (10, 1)}) for i in range(3)]
    assert "max_robots 1" in (select(near, task(max_robots=1)).reason or "")
    reason = select(near, task(max_cost=1.5)).reason or ""
    assert "max_cost 1.5" in reason and "costs 2.00" in reason


@pytest.mark.parametrize(
    ("priority", "chosen"),
    [("time", ("r-1", "r-2")), ("balanced", ("r-3", "r-4")), ("cost", ("r-3", "r-4"))],
)
def test_the_thesis_example_follows_the_priority(priority: str, chosen: tuple[str, ...]) -> None:
    robots = [
        robot(1, {"grabber": (10, 9)}),
        robot(2, {"grabber": (10, 9)}),
        robot(3, {"grabber": (80, 1)}),
        robot(4, {"grabber": (80, 1)}),
    ]
    result = select(robots, task(priority=priority))
    assert [c.robots for c in result.pareto] == [("r-1", "r-2"), ("r-3", "r-4")]
    # Two members: balanced weights tie (broken by cost); "time" weighs T 0.6.
    assert result.chosen is not None and result.chosen.robots == chosen
    assert result.complete and result.bound is not None and result.bound.exact


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(robots_and_task(), st.sampled_from(["exact", "mopso"]))
def test_the_iaas_selection_answers_what_select_answers(
    case: tuple[list[Robot], Task], optimizer: str
) -> None:
    robots, task = case
    problem = CoalitionProblem.build(filter_robots(robots, task), task)
    full = select(robots, task, optimizer, seed=3)  # type: ignore[arg-type]
    for ranking in (True, False):
        got = select_problem(problem, task, optimizer, seed=3, ranking=ranking)  # type: ignore[arg-type]
        assert got.ranking == (full.ranking if ranking else ())
        assert (got.candidates, got.pareto, got.chosen) == (
            full.candidates,
            full.pareto,
            full.chosen,
        )
        assert (got.reason, got.pool, got.complete, got.bound, got.note) == (
            full.reason,
            full.pool,
            full.complete,
            full.bound,
            full.note,
        )
