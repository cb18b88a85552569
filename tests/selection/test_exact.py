import dataclasses

import numpy as np
import pytest
from brute_force import brute_force_front
from instances import random_problem

from robocloud.domain import Coalition, Robot, Task
from robocloud.selection import covering
from robocloud.selection.budget import NO_DEADLINE
from robocloud.selection.choice import choose
from robocloud.selection.covering import CoverSolver
from robocloud.selection.exact import (
    _Sweep,
    cheapest_cover,
    exact_front,
    exact_search,
    one_robot_front,
    prune,
)
from robocloud.selection.filtering import filter_robots
from robocloud.selection.problem import CoalitionProblem


@pytest.mark.parametrize("seed", range(250))
def test_exact_front_and_choice_equal_brute_force(seed: int) -> None:
    problem = random_problem(np.random.default_rng(seed))
    expected = brute_force_front(problem)
    assert exact_front(problem) == expected
    assert choose(exact_front(problem)) == choose(expected)


@pytest.mark.parametrize("seed", range(100))
def test_cheapest_cover_is_a_cheapest_feasible_coalition(seed: int) -> None:
    problem = random_problem(np.random.default_rng(seed))
    expected = brute_force_front(problem)
    witness = cheapest_cover(problem)
    if not expected:
        assert witness is None
        return
    assert witness is not None
    row = np.zeros((1, problem.size), dtype=bool)
    row[0, witness] = True
    assert problem.feasible(row)[0]
    assert problem.cost[witness].sum() == pytest.approx(min(c.cost for c in expected))


def test_pruning_keeps_every_front_member_and_drops_dominated_robots() -> None:
    rng = np.random.default_rng(7)
    n = 3000
    problem = CoalitionProblem(
        ids=tuple(f"r-{i:05d}" for i in range(n)),
        time=rng.uniform(10, 1000, n),
        cost=rng.uniform(1, 50, n),
        uses=rng.random((n, 3)) < 0.4,
        capabilities=("a", "b", "c"),
        need=np.array([2, 1, 1]),
        max_robots=10,
        max_cost=200.0,
        max_time=800.0,
    )
    survivors = prune(problem)
    assert survivors.size < n / 5
    front = exact_front(problem, survivors)
    assert front
    assert {r for c in front for r in c.robots} <= {problem.ids[i] for i in survivors}


CAPABILITY_KINDS = {"light": "sensing", "sound": "sensing", "grabber": "actuating",
                    "kicker": "actuating"}


def fleet_and_task(
    rng: np.random.Generator, execution: str, tight: bool
) -> tuple[list[Robot], Task]:
    robots = []
    for i in range(int(rng.integers(3, 13))):
        names = [n for n in CAPABILITY_KINDS if rng.random() < 0.45] or ["grabber"]
        robots.append(Robot.model_validate({
            "id": f"r-{i:02d}", "cloud": "cloud-a",
            "position": [float(rng.integers(0, 50)), float(rng.integers(0, 50))],
            "speed": 1.0, "battery": 90.0, "status": "idle",
            "travel_cost_per_m": float(rng.choice([0.0, 0.1])),
            "capabilities": {
                n: {"kind": CAPABILITY_KINDS[n], "time": float(rng.integers(1, 6) * 10),
                    "cost": float(rng.integers(1, 6))}
                for n in names
            },
        }))
    wanted = rng.choice(sorted(CAPABILITY_KINDS), size=int(rng.integers(1, 4)), replace=False)
    counts = {str(n): int(rng.integers(1, 3)) for n in wanted}
    task = Task.model_validate({
        "location": [25.0, 25.0],
        "sensing": {n: q for n, q in counts.items() if CAPABILITY_KINDS[n] == "sensing"},
        "actuating": {n: q for n, q in counts.items() if CAPABILITY_KINDS[n] == "actuating"},
        "max_robots": int(rng.integers(1, 5)) if tight else 12,
        "max_cost": float(rng.uniform(5, 30)) if tight else 1e6,
        "max_time": float(rng.uniform(40, 110)) if tight else 1e6,
        "execution": execution,
    })
    return robots, task


@pytest.mark.parametrize("tight", [True, False], ids=["tight", "loose"])
@pytest.mark.parametrize("execution", ["parallel", "sequential"])
@pytest.mark.parametrize("seed", range(40))
def test_exact_equals_brute_force_in_both_modes(seed: int, execution: str, tight: bool) -> None:
    robots, task = fleet_and_task(np.random.default_rng(seed), execution, tight)
    problem = CoalitionProblem.build(filter_robots(robots, task), task)
    assert exact_front(problem) == brute_force_front(problem)


@pytest.mark.parametrize("seed", range(60))
def test_every_tie_is_found(seed: int) -> None:
    """On coarse values many coalitions share a vector: the solver lists every
    cheapest class-count vector, checked against enumeration."""
    import itertools

    size = int(np.random.default_rng(seed).integers(2, 11))
    problem = random_problem(np.random.default_rng(1000 + seed), size)
    keep = prune(problem)
    solver = CoverSolver(problem, keep)
    result = solver.solve(problem.largest_useful_coalition)
    costs = {}
    for size in range(1, problem.size + 1):
        for members in itertools.combinations(keep.tolist(), size):
            covered = problem.uses[list(members)].sum(axis=0) >= problem.need
            if covered.all() and size <= problem.largest_useful_coalition:
                classes = np.zeros(solver.classes, dtype=np.int64)
                for r in members:
                    row = np.flatnonzero((solver.brings == problem.uses[r]).all(axis=1))
                    if row.size:
                        classes[row[0]] += 1
                if (classes <= solver.cap).all():
                    costs[tuple(classes)] = min(costs.get(tuple(classes), np.inf),
                                                float(problem.cost[list(members)].sum()))
    if not costs:
        assert result.status == "infeasible"
        return
    best = min(costs.values())
    assert result.status == "optimal" and result.cost == pytest.approx(best)
    expected = {x for x, c in costs.items() if c <= best + 1e-6}
    assert {tuple(int(v) for v in x) for x in result.ties} == expected


@pytest.fixture(params=["grid", "branch-and-bound"])
def search_path(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """Small searches list every count vector at once; force the branch and
    bound too, so brute force checks both."""
    if request.param == "branch-and-bound":
        monkeypatch.setattr(covering, "GRID_LIMIT", 0)
    return str(request.param)


@pytest.mark.parametrize("seed", range(80))
def test_both_search_paths_equal_brute_force(seed: int, search_path: str) -> None:
    problem = random_problem(np.random.default_rng(5000 + seed))
    assert exact_front(problem) == brute_force_front(problem)


@pytest.mark.parametrize("seed", range(20))
def test_both_search_paths_in_both_modes(seed: int, search_path: str) -> None:
    for execution in ("parallel", "sequential"):
        for tight in (True, False):
            robots, task = fleet_and_task(np.random.default_rng(700 + seed), execution, tight)
            problem = CoalitionProblem.build(filter_robots(robots, task), task)
            assert exact_front(problem) == brute_force_front(problem)


@pytest.mark.parametrize("seed", range(40))
def test_every_tie_is_found_by_branch_and_bound(
    seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(covering, "GRID_LIMIT", 0)
    test_every_tie_is_found(seed)


def one_robot_problem(rng: np.random.Generator, n: int) -> CoalitionProblem:
    """A task one robot can do: one capability, needed once (the sweep's fast path)."""
    base = random_problem(rng, n)
    k = base.uses.shape[1]
    need = np.zeros(k, dtype=np.int64)
    need[int(rng.integers(k))] = 1
    return dataclasses.replace(base, need=need, max_robots=max(1, base.max_robots))


def swept_front(problem: CoalitionProblem) -> list[Coalition]:
    """The general epsilon-constraint sweep, without the one-robot fast path."""
    keep = prune(problem)
    if keep.size == 0:
        return []
    solver = CoverSolver(problem, keep, NO_DEADLINE)
    return _Sweep(problem, solver, NO_DEADLINE).run(problem.largest_useful_coalition, keep).front


@pytest.mark.parametrize("seed", range(150))
def test_a_one_robot_task_takes_the_fast_path_and_its_front_is_brute_forces(seed: int) -> None:
    problem = one_robot_problem(np.random.default_rng(seed), n=int(seed % 16) + 1)
    outcome = exact_search(problem)
    assert outcome.nodes == 0 and outcome.steps <= 1 and outcome.complete  # no covering search
    assert outcome.front == brute_force_front(problem)
    assert outcome.front == swept_front(problem)


@pytest.mark.parametrize("seed", range(20))
def test_a_one_robot_front_among_many_candidates_is_the_sweeps(seed: int) -> None:
    problem = one_robot_problem(np.random.default_rng(1000 + seed), n=500)
    front = exact_search(problem).front
    assert front == swept_front(problem)
    assert all(c.size == 1 for c in front)


@pytest.mark.parametrize("spread", [0.0, 1e-11])  # the very same T, or within the tolerance
def test_a_one_robot_task_over_many_alike_robots_goes_to_the_sweep(spread: float) -> None:
    n = 2000
    order = np.random.default_rng(5).permutation(n)
    problem = CoalitionProblem(
        ids=tuple(f"r-{i:05d}" for i in order),
        time=50.0 + order * spread,
        cost=np.full(n, 3.0),
        uses=np.ones((n, 1), dtype=bool),
        capabilities=("grabber",),
        need=np.array([1]),
        max_robots=1,
        max_cost=10.0,
        max_time=100.0,
    )
    assert one_robot_front(problem, prune(problem)) is None  # past SKYLINE_MAX
    outcome = exact_search(problem)
    assert outcome.steps > 1  # the sweep ran
    assert outcome.front == swept_front(problem)
    assert [c.robots for c in outcome.front] == [("r-00000",)]
