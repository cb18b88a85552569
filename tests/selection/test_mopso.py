"""MOPSO (thesis Algorithm 4): feasible, mutually non-dominated, reproducible, close to exact."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from robocloud.domain import Capability, Coalition, Robot, Task
from robocloud.errors import InvalidInput
from robocloud.selection.filtering import filter_robots
from robocloud.selection.mopso import MopsoSettings, mopso
from robocloud.selection.mopso_repository import (
    Repository,
    crowding_keep,
    first_occurrences,
    grid_cells,
)
from robocloud.selection.pareto import dominates, pareto_front, same_vector
from robocloud.selection.problem import CoalitionProblem

QUICK = MopsoSettings(swarm_size=12, iterations=8)


def make_problem(
    rng: np.random.Generator,
    n: int,
    k: int | None = None,
    tight: bool | None = None,
    coarse: bool | None = None,
) -> CoalitionProblem:
    """A random problem; half of them on a coarse grid so ties in T and C happen."""
    k = int(rng.integers(1, 4)) if k is None else k
    need = rng.integers(1, 4, size=k).astype(np.int64)
    uses = rng.random((n, k)) < rng.uniform(0.25, 0.7)
    coarse = bool(rng.random() < 0.5) if coarse is None else coarse
    if coarse:
        time = rng.integers(1, 8, size=n).astype(float) * 10
        cost = rng.integers(1, 8, size=n).astype(float)
    else:
        time = np.round(rng.uniform(10, 100, size=n), 2)
        cost = np.round(rng.uniform(1, 20, size=n), 2)
    tight = bool(rng.random() < 0.5) if tight is None else tight
    return CoalitionProblem(
        ids=tuple(f"r-{i:02d}" for i in rng.permutation(n)),
        time=time,
        cost=cost,
        uses=uses,
        capabilities=tuple(f"cap{j}" for j in range(k)),
        need=need,
        max_robots=int(rng.integers(1, n + 1)) if tight else n,
        max_cost=float(rng.uniform(5, 40)) if tight else 1e9,
        max_time=float(rng.uniform(20, 80)) if tight else 1e9,
    )


def members(problem: CoalitionProblem, coalition: Coalition) -> np.ndarray:
    row = np.isin(np.array(problem.ids), coalition.robots)
    return np.asarray(row[None, :])


def assert_valid_front(problem: CoalitionProblem, front: list[Coalition]) -> None:
    for coalition in front:
        row = members(problem, coalition)
        assert problem.feasible(row)[0], coalition
        time, cost, size = problem.evaluate(row)
        assert coalition.size == size[0]
        assert coalition.time == pytest.approx(time[0])
        assert coalition.cost == pytest.approx(cost[0])
    for a in front:
        for b in front:
            assert not dominates(a, b), (a, b)
    assert front == pareto_front(front)


def brute_force_front(problem: CoalitionProblem) -> list[Coalition]:
    """Every subset, feasible ones kept, then docs/model.md's front.

    Before the quadratic ``pareto_front``, each size class keeps only the
    points no earlier point (by T, then C) beats on C: a superset of its
    non-dominated points.
    """
    n = problem.size
    rows = ((np.arange(2**n)[:, None] >> np.arange(n)) & 1).astype(bool)
    rows = rows[problem.feasible(rows)]
    if len(rows) == 0:
        return []
    time, cost, size = problem.evaluate(rows)
    keep = np.zeros(len(rows), dtype=bool)
    for n_robots in np.unique(size):
        idx = np.flatnonzero(size == n_robots)
        idx = idx[np.lexsort((cost[idx], time[idx]))]
        earlier = np.concatenate(([np.inf], np.minimum.accumulate(cost[idx])[:-1]))
        keep[idx[cost[idx] <= earlier]] = True
    return pareto_front(problem.coalition(np.flatnonzero(row)) for row in rows[keep])


def same_front(a: list[Coalition], b: list[Coalition]) -> bool:
    return len(a) == len(b) and all(same_vector(x, y) for x, y in zip(a, b, strict=True))


def everyone(problem: CoalitionProblem) -> np.ndarray:
    return np.arange(problem.size, dtype=np.int64)


# --- a small instance whose front is known by hand ---------------------------


def test_golden_front_of_a_hand_made_instance() -> None:
    # Need one A and one B. r0 brings both; r1 and r3 bring A; r2 and r4 bring B.
    problem = CoalitionProblem(
        ids=("r0", "r1", "r2", "r3", "r4"),
        time=np.array([10.0, 1.0, 2.0, 5.0, 20.0]),
        cost=np.array([10.0, 1.0, 2.0, 0.5, 0.1]),
        uses=np.array([[1, 1], [1, 0], [0, 1], [1, 0], [0, 1]], dtype=bool),
        capabilities=("A", "B"),
        need=np.array([1, 1], dtype=np.int64),
        max_robots=5,
        max_cost=100.0,
        max_time=100.0,
    )
    front = mopso(problem, everyone(problem))
    assert [(c.robots, c.time, c.cost, c.size) for c in front] == [
        (("r1", "r2"), 2.0, 3.0, 2),
        (("r2", "r3"), 5.0, 2.5, 2),
        (("r0",), 10.0, 10.0, 1),
        (("r3", "r4"), 20.0, pytest.approx(0.6), 2),
    ]


# --- invariants ---------------------------------------------------------------


@pytest.mark.parametrize("seed", range(30))
def test_front_is_feasible_and_mutually_non_dominated(seed: int) -> None:
    rng = np.random.default_rng(seed)
    problem = make_problem(rng, int(rng.integers(1, 40)))
    pool = rng.permutation(problem.size)[: int(rng.integers(1, problem.size + 1))]
    front = mopso(problem, pool, QUICK)
    assert_valid_front(problem, front)
    allowed = {problem.ids[i] for i in pool}
    assert all(set(c.robots) <= allowed for c in front)


@pytest.mark.parametrize("seed", range(10))
def test_coalitions_are_minimal(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    problem = make_problem(rng, 30, tight=False)
    for coalition in mopso(problem, everyone(problem), QUICK):
        row = members(problem, coalition)
        for i in np.flatnonzero(row[0]):
            smaller = row.copy()
            smaller[0, i] = False
            assert not problem.covers(smaller)[0]


def test_same_seed_same_output_and_seeds_matter() -> None:
    problem = make_problem(np.random.default_rng(7), 60, k=3, tight=False)
    pool = everyone(problem)[:40]
    assert mopso(problem, pool, MopsoSettings(seed=3)) == mopso(
        problem, pool, MopsoSettings(seed=3)
    )
    small = [MopsoSettings(swarm_size=3, iterations=2, seed=s) for s in range(8)]
    fronts = [tuple(mopso(problem, pool, s)) for s in small]
    assert len(set(fronts)) > 1


def test_grid_leader_finds_a_valid_front() -> None:
    for seed in range(10):
        problem = make_problem(np.random.default_rng(200 + seed), 40)
        grid = MopsoSettings(leader="grid", grid_divisions=4, seed=seed)
        front = mopso(problem, everyone(problem), grid)
        assert_valid_front(problem, front)
        assert front == mopso(problem, everyone(problem), grid)


@pytest.mark.parametrize("leader", ["random", "grid"])
def test_repository_size_bounds_the_front(leader: str) -> None:
    problem = make_problem(np.random.default_rng(5), 60, k=3, tight=False, coarse=False)
    full = mopso(problem, everyone(problem), MopsoSettings(leader=leader))  # type: ignore[arg-type]
    assert len(full) > 3
    bounded = MopsoSettings(repository_size=3, leader=leader)  # type: ignore[arg-type]
    front = mopso(problem, everyone(problem), bounded)
    assert 1 <= len(front) <= 3
    assert_valid_front(problem, front)


# --- infeasible and degenerate input ---------------------------------------------


def two_capability_problem(**change: object) -> CoalitionProblem:
    values: dict[str, object] = {
        "ids": ("a", "b", "c"),
        "time": np.array([10.0, 20.0, 30.0]),
        "cost": np.array([5.0, 6.0, 7.0]),
        "uses": np.array([[1, 0], [0, 1], [1, 1]], dtype=bool),
        "capabilities": ("x", "y"),
        "need": np.array([1, 1], dtype=np.int64),
        "max_robots": 3,
        "max_cost": 100.0,
        "max_time": 100.0,
    }
    values.update(change)
    return CoalitionProblem(**values)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "change",
    [
        {"need": np.array([3, 1], dtype=np.int64)},  # only two robots bring x
        {"max_cost": 4.0},  # every robot alone is too dear
        {"max_time": 5.0},  # every robot alone is too slow
        {"max_cost": 6.5, "max_time": 25.0},  # c alone too slow, a + b too dear
        {"max_robots": 1, "max_time": 25.0},  # a + b is two robots
    ],
)
def test_infeasible_problem_gives_nothing(change: dict[str, object]) -> None:
    problem = two_capability_problem(**change)
    assert brute_force_front(problem) == []
    assert mopso(problem, everyone(problem)) == []


def test_empty_pool_gives_nothing() -> None:
    problem = two_capability_problem()
    assert mopso(problem, np.zeros(0, dtype=np.int64)) == []


def test_pool_limits_the_robots() -> None:
    problem = two_capability_problem()
    front = mopso(problem, np.array([0, 1], dtype=np.int64))
    assert [c.robots for c in front] == [("a", "b")]
    assert [c.robots for c in mopso(problem, np.array([2], dtype=np.int64))] == [("c",)]


def test_pool_outside_the_candidates_is_refused() -> None:
    problem = two_capability_problem()
    with pytest.raises(InvalidInput, match="outside"):
        mopso(problem, np.array([0, 3], dtype=np.int64))
    with pytest.raises(InvalidInput):
        mopso(problem, np.array([[0, 1]], dtype=np.int64))


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("swarm_size", 0),
        ("iterations", -1),
        ("repository_size", 0),
        ("leader", "best"),
        ("grid_divisions", 0),
        ("mutation_rate", 1.5),
        ("inertia", float("nan")),
        ("c1", -1.0),
        ("c2", float("inf")),
        ("seed", -1),
        ("swarm_size", 2.5),
    ],
)
def test_settings_are_validated(field: str, value: object) -> None:
    with pytest.raises(InvalidInput) as error:
        MopsoSettings(**{field: value})  # type: ignore[arg-type]
    assert error.value.field == field
    assert error.value.message.endswith(".")


# --- Repository and adaptive grid ---------------------------------------------------


def test_crowding_removes_from_the_most_crowded_hypercube() -> None:
    cells = np.array([0, 0, 0, 0, 0, 1, 1, 2], dtype=np.int64)
    keep = crowding_keep(cells, 5, np.random.default_rng(0))
    assert keep.sum() == 5
    assert np.bincount(cells[keep], minlength=3).tolist() == [2, 2, 1]
    keep = crowding_keep(cells, 4, np.random.default_rng(0))
    assert sorted(np.bincount(cells[keep], minlength=3).tolist()) == [1, 1, 2]


def test_grid_cells_span_the_members() -> None:
    values = np.array([[0.0, 0.0, 1.0], [10.0, 5.0, 1.0], [9.9, 4.9, 1.0]])
    cells = grid_cells(values, 2)
    assert cells[1] == cells[2] != cells[0]


def test_first_occurrences_finds_duplicate_rows() -> None:
    rows = np.zeros((5, 70), dtype=bool)
    rows[1, 69] = rows[2, 3] = rows[3, 69] = True
    assert first_occurrences(rows).tolist() == [0, 1, 2]


def test_repository_keeps_the_non_dominated_within_its_size() -> None:
    rng = np.random.default_rng(0)
    rep = Repository(width=20, capacity=10, divisions=5)
    for _ in range(20):
        positions = rng.random((15, 20)) < 0.3
        # A trade-off line: N constant, C falls as T rises, plus dominated noise.
        t = rng.uniform(0, 1, 15)
        objectives = np.column_stack((t, 1 - t + rng.uniform(0, 0.2, 15), np.full(15, 3.0)))
        rep.update(positions, objectives, rng)
        assert 1 <= len(rep) <= 10
        assert len(first_occurrences(rep.members)) == len(rep)
    t, c = rep.objectives[:, 0], rep.objectives[:, 1]
    for i in range(len(rep)):
        assert not ((t <= t[i]) & (c <= c[i]) & ((t < t[i]) | (c < c[i]))).any()


def test_grid_roulette_favours_lonely_members() -> None:
    rep = Repository(width=10, capacity=50, divisions=4)
    # One member alone near T = 0, nine packed near T = 1 (all on one trade-off line).
    t = np.concatenate(([0.0], np.linspace(0.95, 1.0, 9)))
    objectives = np.column_stack((t, 1.0 - t, np.ones(10)))
    rep.update(np.eye(10, dtype=bool), objectives, np.random.default_rng(0))
    assert len(rep) == 10
    lonely = int(np.flatnonzero(rep.objectives[:, 0] == 0.0)[0])
    picks = rep.leaders(4000, "grid", np.random.default_rng(1))
    # Hypercube fitness 10/1 against 10/9: the lonely member is drawn 90% of the time.
    assert 0.85 < np.mean(picks == lonely) < 0.95
    uniform = rep.leaders(4000, "random", np.random.default_rng(1))
    assert 0.05 < np.mean(uniform == lonely) < 0.15


# --- property test over random fleets -------------------------------------------------

NAMES = ("light", "camera", "grabber", "pump")


@st.composite
def fleets(draw: st.DrawFn) -> tuple[list[Robot], Task]:
    count = draw(st.integers(1, 25))
    small = st.floats(0.0, 50.0, allow_nan=False)
    robots = []
    for i in range(count):
        names = draw(st.lists(st.sampled_from(NAMES), min_size=1, max_size=3, unique=True))
        robots.append(
            Robot(
                id=f"r-{i:03d}",
                cloud="cloud-a",
                position=[draw(small), draw(small)],
                speed=draw(st.floats(0.5, 3.0)),
                battery=draw(st.floats(0.0, 100.0)),
                status=draw(st.sampled_from(["idle", "idle", "idle", "busy"])),
                travel_cost_per_m=draw(st.floats(0.0, 0.2)),
                capabilities={
                    name: Capability(
                        kind="sensing" if name in NAMES[:2] else "actuating",
                        time=draw(small),
                        cost=draw(small),
                    )
                    for name in names
                },
            )
        )
    required = draw(st.lists(st.sampled_from(NAMES), min_size=1, max_size=4, unique=True))
    counts = {name: draw(st.integers(1, 2)) for name in required}
    task = Task(
        location=[draw(small), draw(small)],
        sensing={n: c for n, c in counts.items() if n in NAMES[:2]},
        actuating={n: c for n, c in counts.items() if n not in NAMES[:2]},
        max_robots=draw(st.integers(1, 8)),
        max_cost=draw(st.floats(10.0, 300.0)),
        max_time=draw(st.floats(20.0, 200.0)),
        min_battery=draw(st.floats(0.0, 50.0)),
        execution=draw(st.sampled_from(["parallel", "sequential"])),
    )
    return robots, task


@pytest.mark.slow  # seconds of work: in make test, not in make check
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(fleets(), st.integers(0, 2**32), st.sampled_from(["random", "grid"]))
def test_property_random_fleets(fleet: tuple[list[Robot], Task], seed: int, leader: str) -> None:
    robots, task = fleet
    problem = CoalitionProblem.build(filter_robots(robots, task), task)
    run = MopsoSettings(swarm_size=10, iterations=6, leader=leader, seed=seed)  # type: ignore[arg-type]
    front = mopso(problem, everyone(problem), run)
    assert_valid_front(problem, front)
    assert front == mopso(problem, everyone(problem), run)
    if problem.size <= 12 and not brute_force_front(problem):
        assert front == []


# --- against brute force --------------------------------------------------------------


@pytest.mark.slow  # seconds of work: in make test, not in make check
def test_matches_the_brute_force_front_on_small_instances() -> None:
    rng = np.random.default_rng(2024)
    matches = identical = 0
    instances = 200
    for _ in range(instances):
        problem = make_problem(rng, int(rng.integers(4, 15)))
        truth = brute_force_front(problem)
        front = mopso(problem, everyone(problem))
        assert_valid_front(problem, front)
        matches += same_front(front, truth)
        identical += front == truth
    rate = matches / instances
    print(
        f"MOPSO front equals the brute-force front on {rate:.1%} of {instances} instances "
        f"({identical / instances:.1%} with the same coalitions)"
    )
    assert rate >= 0.8
