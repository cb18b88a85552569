"""Large-neighbourhood search: the anytime method for missions too large to prove.

Start from the construction's plan; then, until the time is up, free a few
robots (the neighbourhood: those that finish last, and others drawn at
random, in half the steps their partners at shared tasks first) and let
CP-SAT share out again the tasks they do, warm-started from the current
plan, while every other robot keeps its coalitions and its order (their
times may still move). A better plan (a shorter makespan, or the same
with robots done earlier in sum) replaces the current one. The neighbourhood
grows when CP-SAT proves its part optimal quickly and shrinks when it runs
out of time, so the steps stay a fraction of a second.

Each step builds the exact model of its part only: the kept robots' routes
as fixed chains of constraints, circuits for the freed robots over the tasks
they share out; building the whole model and fixing most of it was slower
than the step itself on 50 tasks and 20 robots.
"""

from __future__ import annotations

import random
import time
from dataclasses import dataclass

from ortools.sat.python import cp_model

from robocloud.planning.cpsat import MissionModel, choose_scale, make_solver
from robocloud.planning.problem import Problem
from robocloud.planning.schedule import Schedule

STEP_LIMIT = 0.02  # CP-SAT's deterministic time per step at most (about seconds)
FIRST_SIZE = 3  # robots freed in the first step
WORKERS = 1


@dataclass(frozen=True)
class Search:
    schedule: Schedule
    steps: int
    improvements: int


def _score(schedule: Schedule) -> tuple[float, float]:
    return (round(schedule.makespan, 6), round(sum(schedule.arrival), 6))


def improve(
    problem: Problem,
    schedule: Schedule,
    time_limit: float,
    seed: int,
) -> Search:
    """The best plan found from ``schedule`` within ``time_limit`` seconds."""
    deadline = time.monotonic() + time_limit
    rng = random.Random(seed)
    n = problem.n_robots
    weight = n + 1
    scale = choose_scale(schedule.makespan)
    best = schedule
    size = min(FIRST_SIZE, n)
    steps = improvements = 0
    while n > 1:
        left = deadline - time.monotonic()
        if left < 0.05:
            break
        steps += 1
        latest = max(best.arrival)
        critical = [i for i in range(n) if best.arrival[i] >= latest - 1e-6]
        others = [i for i in range(n) if i not in critical]
        rng.shuffle(others)
        rng.shuffle(critical)
        if rng.random() < 0.5:
            # Half the steps free the critical robots' partners first: the robots
            # they wait for at shared tasks.
            partners = {
                j for i in critical for k in best.sequences[i] for j in best.coalitions[k]
            }
            others.sort(key=lambda i: i not in partners)
        free = set((critical + others)[: max(size, 1)])
        # The freed robots share out the tasks they do now; the others keep theirs.
        theirs = {k for i in free for k in best.sequences[i]}
        kept = {i: best.sequences[i] for i in range(n) if i not in free}
        sub = MissionModel(problem, best.makespan, scale, fixed=kept, allowed=theirs)
        sub.model.minimize(weight * sub.makespan + sum(sub.arrival))
        sub.hint(best)
        solver = make_solver(left, seed + steps, WORKERS)
        # Counted in CP-SAT's deterministic time, so a step's result does not
        # depend on the machine's load (only the number of steps does).
        solver.parameters.max_deterministic_time = STEP_LIMIT
        solver.parameters.cp_model_presolve = False
        status = solver.solve(sub.model)
        if status == cp_model.OPTIMAL and solver.deterministic_time < STEP_LIMIT / 2:
            size = min(n, size + 1)
        elif status != cp_model.OPTIMAL:
            size = max(2, size - 1)
        if status in (cp_model.OPTIMAL, cp_model.FEASIBLE):
            found = sub.read(solver)
            if _score(found) < _score(best):
                best = found
                improvements += 1
    return Search(best, steps, improvements)
