"""A good first plan, fast: list scheduling by earliest start.

Repeatedly, among the tasks whose predecessors are all planned, take the one
that can start first, with the coalition that lets it start first, and append
it to its members' routes. The earliest coalition of one task is found
exactly by :func:`earliest_coalition`. The plan warm-starts the exact model
and the large-neighbourhood search (``lns.py``).
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence

from robocloud.planning.problem import Problem
from robocloud.planning.schedule import Schedule, timed


def earliest_coalition(
    problem: Problem, k: int, ready_at: Sequence[float]
) -> tuple[float, tuple[int, ...], frozenset[int]] | None:
    """The earliest time task ``k`` can start, a minimal coalition that makes it, and
    the robots taken on the way (only a change to one of them can change the answer).

    ``ready_at[i]``: when robot i could be at the task. Taking the robots in
    order of arrival and stopping as soon as those taken cover the task gives
    the earliest start: no coalition can start before its last member arrives,
    and any coalition that covers only with robots arriving by t is covered by
    the robots arriving by t.
    """
    order = sorted(
        (i for i in range(problem.n_robots) if problem.useful[i][k]), key=lambda i: (ready_at[i], i)
    )
    missing = dict(problem.need[k])
    taken: list[int] = []
    for i in order:
        if not any(missing.get(c, 0) > 0 for c in problem.brings[i]):
            continue
        taken.append(i)
        for c in problem.brings[i]:
            if missing.get(c, 0) > 0:
                missing[c] -= 1
        if not any(missing.values()):
            return ready_at[i], problem.minimal(k, taken), frozenset(taken)
    return None


def best_construction(problem: Problem) -> Schedule | None:
    """The shorter of the two rankings' plans (neither is better on every mission)."""
    plans = [p for p in (construct(problem), construct(problem, lookahead=False)) if p]
    return min(plans, key=lambda p: p.makespan, default=None)


def construct(
    problem: Problem, seed: int | None = None, *, lookahead: bool = True
) -> Schedule | None:
    """The list-scheduling plan; with a seed, ties and near-ties are broken at random.
    ``lookahead``: rank a task by its finish less the work of its successors, else by
    its finish. None when some task cannot be covered."""
    rng = random.Random(seed)
    m, n = problem.n_tasks, problem.n_robots
    before = problem.predecessors()
    free_at = [0.0] * n
    last: list[int | None] = [None] * n
    end = [0.0] * m
    planned = [False] * m
    coalitions: list[tuple[int, ...]] = [()] * m
    sequences: list[list[int]] = [[] for _ in range(n)]
    # Per ready task: (rank, members, finish, robots taken). Planning a task changes
    # only its members' times, so only the tasks that took one of them are redone.
    cache: dict[int, tuple[float, tuple[int, ...], float, frozenset[int]]] = {}
    tail = _tails(problem) if lookahead else [0.0] * m
    for _ in range(m):
        for k in range(m):
            if k in cache or planned[k] or not all(planned[j] for j in before[k]):
                continue
            released = max((end[j] for j in before[k]), default=0.0)
            ready_at = [
                (
                    problem.travel_from_start(i, k)
                    if last[i] is None
                    else free_at[i] + problem.travel_between(i, last[i], k)  # type: ignore[arg-type]
                )
                if problem.useful[i][k]
                else math.inf
                for i in range(n)
            ]
            found = earliest_coalition(problem, k, ready_at)
            if found is None:
                return None
            _, members, taken = found
            start = max(released, *(ready_at[i] for i in members))
            finish = start + problem.duration(k, members)
            # Rank by finish, less the work its successors still need after it (a
            # task others wait for goes first); a seed perturbs the ranking a little.
            rank = (finish - tail[k]) * (1.0 + (rng.random() * 0.1 if seed is not None else 0.0))
            cache[k] = (rank, members, finish, taken)
        k = min(cache, key=lambda j: (cache[j][0], j))
        _, members, finish, _ = cache.pop(k)
        planned[k] = True
        coalitions[k] = members
        end[k] = finish  # appending a task never moves the ones planned before it
        for i in members:
            sequences[i].append(k)
            free_at[i] = finish
            last[i] = k
        moved = set(members)
        for j in [j for j, entry in cache.items() if entry[3] & moved]:
            del cache[j]
    return timed(problem, coalitions, sequences)


def _tails(problem: Problem) -> list[float]:
    """For each task, the least work of the longest chain of successors after it."""
    order = problem.topological_order()
    assert order is not None
    shortest = [
        min((problem.work[i][k] for i in range(problem.n_robots) if problem.useful[i][k]),
            default=0.0)
        for k in range(problem.n_tasks)
    ]
    after: list[list[int]] = [[] for _ in range(problem.n_tasks)]
    for j, k in problem.precedence:
        after[j].append(k)
    tail = [0.0] * problem.n_tasks
    for k in reversed(order):
        tail[k] = max((shortest[s] + tail[s] for s in after[k]), default=0.0)
    return tail
