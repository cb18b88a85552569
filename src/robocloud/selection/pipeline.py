"""The network level virtualization algorithm, end to end (thesis Algorithm 1).

filter (Algorithm 2) -> rank with PROMETHEE II (Algorithm 3) -> pool of the
best ranked -> search for Pareto-optimal coalitions (MOPSO, Algorithms 4 and
5, or the exact optimizer) -> drop those over the time and cost thresholds ->
choose one with PROMETHEE II. Every stage is a pure function of its inputs;
the same seed gives the same answer.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Literal

from robocloud.domain import Robot, Task
from robocloud.errors import InvalidInput
from robocloud.selection.choice import choose, within_thresholds
from robocloud.selection.exact import exact_front, exact_work, prune
from robocloud.selection.filtering import filter_robots
from robocloud.selection.mopso import MopsoSettings, mopso
from robocloud.selection.pool import build_pool
from robocloud.selection.problem import CoalitionProblem
from robocloud.selection.ranking import rank_candidates
from robocloud.selection.reasons import infeasibility_reason
from robocloud.selection.result import OptimizerName, SelectionResult

OptimizerChoice = Literal["auto", "exact", "mopso"]

# ``auto`` takes the exact optimizer up to this many dynamic-program cells
# (robots after pruning x coverage states x sizes); measured in
# benchmarks/, this many take about as long as one MOPSO run.
EXACT_BUDGET = 200_000


def select(
    robots: Sequence[Robot],
    task: Task,
    optimizer: OptimizerChoice = "auto",
    *,
    seed: int = 0,
    pool_size: int | None = None,
    settings: MopsoSettings | None = None,
) -> SelectionResult:
    if optimizer not in ("auto", "exact", "mopso"):
        raise InvalidInput(
            f"optimizer must be auto, exact or mopso, not {optimizer!r}.", "optimizer"
        )
    if pool_size is not None and pool_size < 1:
        raise InvalidInput("pool_size must be at least 1.", "pool_size")
    started = time.perf_counter()
    candidates = filter_robots(robots, task)
    problem = CoalitionProblem.build(candidates, task)
    order, _ = rank_candidates(problem, task.priority)
    survivors = prune(problem)
    used: OptimizerName
    if optimizer == "auto":
        used = "exact" if exact_work(problem, survivors) <= EXACT_BUDGET else "mopso"
    else:
        used = optimizer
    pool: tuple[str, ...] = ()
    if used == "exact":
        front = exact_front(problem, survivors)
    else:
        members = build_pool(problem, order, pool_size or task.max_robots, survivors)
        pool = tuple(problem.ids[i] for i in members)
        if settings is None:
            settings = MopsoSettings(seed=seed)
        front = mopso(problem, members, settings)
    front = within_thresholds(front, task.max_time, task.max_cost)
    chosen = choose(front)
    reason = None if chosen is not None else infeasibility_reason(problem, task)
    return SelectionResult(
        candidates=problem.size,
        ranking=tuple(problem.ids[i] for i in order),
        pareto=tuple(front),
        chosen=chosen,
        reason=reason,
        optimizer=used,
        elapsed_ms=(time.perf_counter() - started) * 1000.0,
        pool=pool,
    )
