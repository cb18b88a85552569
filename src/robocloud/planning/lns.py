"""Large-neighbourhood search: the anytime method for missions too large to prove.

Start from the construction's plan; then, until the time is up, free a few
robots (the neighbourhood: those that finish last, and others drawn at
random; or, in a third of the steps each, first the robots it waits for, or
the least busy robots able to take one of its tasks) and let
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


def critical_chain(problem: Problem, schedule: Schedule, robot: int) -> set[int]:
    """The robots whose lateness makes ``robot`` late: going back from its last task,
    through the predecessor that ended last or the member that arrived last."""
    chain = {robot}
    before = problem.predecessors()
    sequence = schedule.sequences[robot]
    current: int | None = sequence[-1] if sequence else None
    seen: set[int] = set()
    while current is not None and current not in seen:
        k = current
        seen.add(k)
        start = schedule.start[k]
        chain.update(schedule.coalitions[k])
        current = next((j for j in before[k] if schedule.end[j] >= start - 1e-6), None)
        if current is not None:
            continue
        for i in schedule.coalitions[k]:
            mine = schedule.sequences[i]
            at = mine.index(k)
            if at == 0:
                continue
            previous = mine[at - 1]
            if schedule.end[previous] + problem.travel_between(i, previous, k) >= start - 1e-6:
                current = previous
                break
    return chain


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
        strategy = rng.randrange(3)
        if strategy == 1:
            # Free first the robots of the critical chain: those the last robot
            # waits for, at shared tasks or through precedence.
            chain = critical_chain(problem, best, rng.choice(critical))
            others.sort(key=lambda i: i not in chain)
        elif strategy == 2:
            # Free first the least busy robots that could take a task of the last one.
            theirs_now = [k for i in critical for k in best.sequences[i]]
            able = {i for i in others if any(problem.useful[i][k] for k in theirs_now)}
            others.sort(key=lambda i: (i not in able, best.arrival[i]))
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
