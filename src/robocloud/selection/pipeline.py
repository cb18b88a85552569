"""The network level virtualization algorithm, end to end (thesis Algorithm 1).

filter (Algorithm 2) -> rank with PROMETHEE II (Algorithm 3) -> cheap
infeasibility tests -> pool of the best ranked -> search for Pareto-optimal
coalitions (MOPSO, Algorithms 4 and 5, or the exact optimizer) -> drop those
over the time and cost thresholds -> choose one with PROMETHEE II, weighted
by the task's priority. Every stage is a pure function of its inputs; the
same seed gives the same answer, as long as the time budget does not cut the
search (a cut search says so in ``complete``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import Literal

import numpy as np

from robocloud.domain import RobotLike, Task
from robocloud.errors import InvalidInput
from robocloud.selection.budget import Deadline
from robocloud.selection.choice import choose, within_thresholds
from robocloud.selection.exact import EXACT, Bound, exact_search, prune
from robocloud.selection.feasibility import quick_infeasibility
from robocloud.selection.filtering import filter_robots
from robocloud.selection.mopso import MopsoSettings, mopso_search
from robocloud.selection.pool import build_pool, seed_covers
from robocloud.selection.problem import CoalitionProblem
from robocloud.selection.ranking import rank_candidates
from robocloud.selection.reasons import infeasibility_reason, out_of_time
from robocloud.selection.result import OptimizerName, SelectionResult

OptimizerChoice = Literal["auto", "exact", "mopso"]

# The time budget of a selection when the caller names none, in seconds.
DEFAULT_BUDGET_S = 2.0


def resolve(optimizer: OptimizerChoice) -> OptimizerName:
    """What ``auto`` runs: the exact optimizer, always.

    It takes about as long as MOPSO and its front is the true one, which
    MOPSO's only approaches (benchmarks/results/design-notes.md, auto-exact);
    when the budget cuts it, its partial front comes with a certified bound,
    which MOPSO cannot give.
    """
    return "mopso" if optimizer == "mopso" else "exact"


def _check(optimizer: str, pool_size: int | None, budget_s: float | None) -> None:
    if optimizer not in ("auto", "exact", "mopso"):
        raise InvalidInput(
            f"optimizer must be auto, exact or mopso, not {optimizer!r}.", "optimizer"
        )
    if pool_size is not None and pool_size < 1:
        raise InvalidInput("pool_size must be at least 1.", "pool_size")
    if budget_s is not None and (
        isinstance(budget_s, bool)
        or not isinstance(budget_s, int | float)
        or not math.isfinite(budget_s)
        or budget_s <= 0
    ):
        raise InvalidInput("budget_s must be a positive number of seconds.", "budget_s")


def _bound_note(bound: Bound | None, deadline: Deadline, steps: int) -> str:
    budget = f"of {deadline.budget_s:g} s " if deadline.budget_s is not None else ""
    head = f"The time budget {budget}cut the exact search after {steps} steps"
    if bound is None:
        return f"{head}; no feasible coalition had been found."
    return (
        f"{head}: every feasible coalition is matched by one of this front at most "
        f"{bound.time:.3f} s slower, {bound.cost:.2f} dearer and {bound.size} robots larger."
    )


def select(
    robots: Sequence[RobotLike],
    task: Task,
    optimizer: OptimizerChoice = "auto",
    *,
    seed: int = 0,
    pool_size: int | None = None,
    settings: MopsoSettings | None = None,
    budget_s: float | None = DEFAULT_BUDGET_S,
) -> SelectionResult:
    """Algorithm 1 within ``budget_s`` seconds (None: no limit).

    The budget is checked between steps of the search: a cut search returns
    the feasible coalitions found so far, ``complete=False``, and for the
    exact optimizer a certified bound on how far they are from the true front.

    ``robots`` may be ``Robot`` objects or any records with the same fields
    (``RobotLike``); the result's ``stages`` says how long filtering (with
    each candidate's t_i and c_i), ranking and optimisation took.
    """
    _check(optimizer, pool_size, budget_s)
    started = time.perf_counter()
    deadline = Deadline.after(budget_s)
    candidates = filter_robots(robots, task)
    problem = CoalitionProblem.build(candidates, task)
    filtered = time.perf_counter()
    return _select(
        problem, task, optimizer, seed, pool_size, settings, started, filtered, deadline
    )


def select_problem(
    problem: CoalitionProblem,
    task: Task,
    optimizer: OptimizerChoice = "auto",
    *,
    seed: int = 0,
    pool_size: int | None = None,
    settings: MopsoSettings | None = None,
    budget_s: float | None = DEFAULT_BUDGET_S,
    ranking: bool = True,
) -> SelectionResult:
    """``select`` after its filtering: Algorithm 1 over candidates already filtered.

    The IaaS filters its fleet's columns itself (``robocloud.selection.columns``)
    and hands the worker process only the candidates' terms; this is the same
    pipeline from the ranking on, so the answer is ``select``'s.

    ``ranking=False``: the result's ``ranking`` is left empty, and with the
    exact optimizer (which does not use it) the ranking is not computed. The
    IaaS keeps no ranking, and ranking took a large share of the selection
    (benchmarks/results/design-notes.md, no-ranking); the Pareto front and
    the choice are the same.
    """
    _check(optimizer, pool_size, budget_s)
    started = time.perf_counter()
    deadline = Deadline.after(budget_s)
    return _select(
        problem, task, optimizer, seed, pool_size, settings, started, started, deadline, ranking
    )


def _select(
    problem: CoalitionProblem,
    task: Task,
    optimizer: OptimizerChoice,
    seed: int,
    pool_size: int | None,
    settings: MopsoSettings | None,
    started: float,
    filtered: float,
    deadline: Deadline,
    ranking: bool = True,
) -> SelectionResult:
    """From the ranking on; ``started`` and ``filtered`` time the stages before it."""
    used = resolve(optimizer)
    if ranking or used == "mopso":
        order, _ = rank_candidates(problem, task.priority)
    else:
        order = np.zeros(0, dtype=np.int64)
    ranked = time.perf_counter()

    def result(**fields: object) -> SelectionResult:
        ended = time.perf_counter()
        return SelectionResult(
            candidates=problem.size,
            ranking=tuple(np.array(problem.ids, dtype=object)[order].tolist()) if ranking else (),
            optimizer=used,
            elapsed_ms=(ended - started) * 1000.0,
            stages=(
                ("filtering", (filtered - started) * 1000.0),
                ("ranking", (ranked - filtered) * 1000.0),
                ("optimisation", (ended - ranked) * 1000.0),
            ),
            **fields,  # type: ignore[arg-type]
        )

    quick = quick_infeasibility(problem, task)
    if quick is not None:
        return result(pareto=(), chosen=None, reason=quick, searched=False)
    survivors = prune(problem)
    pool: tuple[str, ...] = ()
    bound: Bound | None = None
    note: str | None = None
    if used == "exact":
        outcome = exact_search(problem, survivors, deadline)
        front, complete, bound = outcome.front, outcome.complete, outcome.bound
        if not complete:
            note = _bound_note(bound, deadline, outcome.steps)
    else:
        seeds = seed_covers(problem, survivors, deadline)
        members = build_pool(
            problem, order, pool_size or task.max_robots, survivors, deadline, seeds
        )
        pool = tuple(problem.ids[i] for i in members)
        if settings is None:
            settings = MopsoSettings(seed=seed)
        search = mopso_search(problem, members, settings, seeds=seeds, deadline=deadline)
        front, complete = search.front, search.complete
        if not complete:
            note = (
                f"The time budget of {deadline.budget_s:g} s cut MOPSO after "
                f"{search.iterations} of {settings.iterations} iterations."
            )
    front = within_thresholds(front, task.max_time, task.max_cost)
    chosen = choose(front, task.priority)
    reason = None
    if chosen is None:
        reason = out_of_time(deadline) if not complete else None
        reason = reason or infeasibility_reason(problem, task, deadline)
        complete = complete and reason != out_of_time(deadline)
    elif complete and used == "exact":
        bound = EXACT
    return result(
        pareto=tuple(front),
        chosen=chosen,
        reason=reason,
        pool=pool,
        complete=complete,
        bound=bound if chosen is not None else None,
        note=note,
    )
