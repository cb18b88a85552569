import numpy as np
import pytest
from brute_force import brute_force_front
from instances import random_problem

from robocloud.selection.choice import choose
from robocloud.selection.exact import cheapest_cover, exact_front, prune
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
