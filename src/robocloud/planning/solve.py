"""Plan a mission: ``solve(problem, time_limit, seed)``.

Small missions go to the exact model (``cpsat.py``), warm-started from the
construction (``construction.py``): it proves its plan optimal when it can
within the time limit. Larger ones take the anytime method: the construction,
then large-neighbourhood search (``lns.py``) until the time limit (for
mid-sized ones, half of it, then the exact model warm-started from its plan).
Either way the plan comes with a lower bound on the makespan (CP-SAT's, or
``bounds.py``'s when larger) and the gap between them.

CP-SAT runs in a child process (``worker.py``): OR-Tools bundles its own
HiGHS library under the same name as the ``highspy`` package the coalition
selection uses (``libhighs.so.1``, versions 1.12 and 1.15), and a process
can load only one of them; whichever is imported second fails. The child
imports OR-Tools and never the selection, so both work from any process.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace

from robocloud.planning.bounds import lower_bound
from robocloud.planning.construction import best_construction
from robocloud.planning.plan import Method, Plan
from robocloud.planning.problem import Problem
from robocloud.planning.schedule import Schedule

# Up to this many (tasks squared times robots), the exact model: it proves
# small missions at once, and beyond it the search is what improves a plan
# within the time limit (benchmarks/results/design-notes.md, exact-size).
EXACT_SIZE = 600
# Up to this size the anytime method gives its second half to the exact model,
# warm-started from the search's plan (15 tasks and 5 robots, 1,125: 634 and 590
# after 10 s of search alone, 611 and 570, the proven optimum, this way; at 30
# and 10 the exact model added nothing in 5 s).
FINISH_EXACT_SIZE = 2_000
DEFAULT_TIME_LIMIT = 10.0

def choose_method(problem: Problem) -> Method:
    size = problem.n_tasks**2 * problem.n_robots
    return "exact" if size <= EXACT_SIZE else "anytime"


def solve(
    problem: Problem,
    time_limit: float = DEFAULT_TIME_LIMIT,
    seed: int = 0,
    method: Method | None = None,
) -> Plan:
    """The best plan found within ``time_limit`` seconds; the same seed, the same plan
    (unless the time limit cuts the search at a different step).

    Runs :func:`solve_here` in a child process (see the module's docstring);
    the time limit covers the child's start.
    """
    from robocloud.planning.worker import run_worker

    started = time.perf_counter()
    plan = run_worker(problem, time_limit, seed, method)
    return replace(plan, elapsed_s=time.perf_counter() - started)


def solve_all(
    problems: Sequence[Problem],
    time_limit: float = DEFAULT_TIME_LIMIT,
    seed: int = 0,
    method: Method | None = None,
) -> list[Plan]:
    """``solve`` for each problem, in one child process (its start paid once);
    ``elapsed_s`` is each plan's own time in the child."""
    from robocloud.planning.worker import run_batch

    return run_batch(problems, time_limit, seed, method)


def solve_here(
    problem: Problem,
    time_limit: float = DEFAULT_TIME_LIMIT,
    seed: int = 0,
    method: Method | None = None,
    started: float | None = None,
) -> Plan:
    """``solve`` in this process: it imports OR-Tools (never with ``highspy`` loaded).

    ``started``: the ``time.perf_counter()`` the time limit counts from."""
    from robocloud.planning.cpsat import BALANCED_SLACK, MissionModel, trivial_horizon
    from robocloud.planning.lns import improve

    started = time.perf_counter() if started is None else started
    method = method or choose_method(problem)

    def done(
        schedule: Schedule | None, bound: float | None, optimal: bool, reason: str | None = None
    ) -> Plan:
        return Plan(schedule, bound, optimal, method, time.perf_counter() - started, reason)

    missing = problem.uncoverable()
    if missing is not None:
        k, capability = missing
        count = problem.need[k][capability]
        have = sum(1 for b in problem.brings if capability in b)
        return done(None, None, False,
                    f"task {problem.task_ids[k]} needs {count} robots bringing {capability!r}, "
                    f"but only {have} of the candidates do.")
    first = best_construction(problem)
    assert first is not None  # every task can be covered
    analytic = lower_bound(problem)
    if problem.n_tasks == 0:
        return done(first, first.makespan, True)
    best, bound, optimal = first, analytic, False
    middle = False
    if method == "anytime":
        left = time_limit - (time.perf_counter() - started)
        middle = problem.n_tasks**2 * problem.n_robots <= FINISH_EXACT_SIZE
        # Mid-sized missions: the search stalls after a while where the exact
        # model, warm-started from its plan, still improves and finds a bound.
        best = improve(problem, first, left / 2 if middle else left, seed).schedule
    if method == "exact" or middle:
        horizon = best.makespan
        if problem.priority != "time":
            # A cheaper plan may be longer than the first one: room up to a bound no
            # plan needs to pass (every task alone, one after another), or max_time.
            horizon = max(horizon * BALANCED_SLACK, trivial_horizon(problem))
            if problem.max_time is not None:
                horizon = min(horizon, max(problem.max_time, best.makespan))
        model = MissionModel(problem, horizon)
        left = time_limit - (time.perf_counter() - started)
        outcome = model.solve(max(0.01, left), seed, hint=best)
        if outcome.infeasible:
            return done(None, None, False, _too_long(problem))
        best = outcome.schedule or best
        bound = max(outcome.lower_bound, analytic)
        optimal = outcome.optimal
    bound = min(bound, best.makespan)
    if problem.max_time is not None and best.makespan > problem.max_time + 1e-6:
        return done(None, bound, False, _too_long(problem, best.makespan))
    return done(best, bound, optimal)


def _too_long(problem: Problem, found: float | None = None) -> str:
    if found is None:
        return f"no plan can finish within max_time ({problem.max_time:g} s)."
    return (
        f"the shortest plan found takes {found:.1f} s, more than max_time "
        f"({problem.max_time:g} s)."
    )
