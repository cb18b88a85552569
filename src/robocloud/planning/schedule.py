"""A plan: each task's coalition, each robot's order, and the times they give.

Every solver hands back *what* (coalitions) and *in which order* (each robot's
sequence); :func:`timed` turns that into times, each task starting as early as
its members' arrivals and its predecessors allow. The times are computed in
floating point from the problem's own numbers, so a solver that works on
rounded integers (CP-SAT) still reports the exact makespan of its plan.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypeVar

from robocloud.planning.problem import Problem

T = TypeVar("T", int, float)


@dataclass(frozen=True)
class Schedule:
    coalitions: tuple[tuple[int, ...], ...]  # per task, robot indexes, sorted
    sequences: tuple[tuple[int, ...], ...]  # per robot, task indexes in order
    start: tuple[float, ...]
    end: tuple[float, ...]
    arrival: tuple[float, ...]  # per robot: when it is done (at the end place, if any)
    makespan: float
    cost: float


def sequences_of(
    problem: Problem, coalitions: Sequence[Sequence[int]], start: Sequence[float]
) -> tuple[tuple[int, ...], ...]:
    """Each robot's tasks ordered by start time (ties by task index)."""
    mine: list[list[int]] = [[] for _ in range(problem.n_robots)]
    for k, members in enumerate(coalitions):
        for i in members:
            mine[i].append(k)
    return tuple(tuple(sorted(ks, key=lambda k: (start[k], k))) for ks in mine)


def earliest(
    problem: Problem,
    coalitions: Sequence[Sequence[int]],
    sequences: Sequence[Sequence[int]],
    from_start: Callable[[int, int], T],
    between: Callable[[int, int, int], T],
    duration: Callable[[int, Sequence[int]], T],
    zero: T,
) -> tuple[list[T], list[T]] | None:
    """Each task's earliest start and end under this plan, in the number type the
    three measures give (floats here, CP-SAT's scaled integers for its hints);
    None if the robots' orders and precedence form a cycle.

    A task starts when its last member has arrived (each from its previous
    task, or from its start) and its predecessors have ended.
    """
    m = problem.n_tasks
    position = [0] * problem.n_robots  # next index in each robot's sequence
    before = problem.predecessors()
    start = [zero] * m
    end = [zero] * m
    done = [False] * m
    last: list[int | None] = [None] * problem.n_robots
    left = m
    while left:
        progressed = False
        for k in range(m):
            if done[k] or not all(done[j] for j in before[k]):
                continue
            members = coalitions[k]
            if not all(
                position[i] < len(sequences[i]) and sequences[i][position[i]] == k for i in members
            ):
                continue  # some member has other tasks to do first
            t = max((end[j] for j in before[k]), default=zero)
            for i in members:
                previous = last[i]
                arrive = (
                    from_start(i, k)
                    if previous is None
                    else end[previous] + between(i, previous, k)
                )
                t = max(t, arrive)
            start[k] = t
            end[k] = t + duration(k, members)
            for i in members:
                position[i] += 1
                last[i] = k
            done[k] = True
            left -= 1
            progressed = True
        if not progressed:
            return None
    return start, end


def timed(
    problem: Problem,
    coalitions: Sequence[Sequence[int]],
    sequences: Sequence[Sequence[int]],
) -> Schedule | None:
    """The plan with its earliest times (None if its orders and precedence form a cycle)."""
    times = earliest(
        problem,
        coalitions,
        sequences,
        problem.travel_from_start,
        problem.travel_between,
        problem.duration,
        0.0,
    )
    if times is None:
        return None
    start, end = times
    arrival = []
    cost = 0.0
    for i in range(problem.n_robots):
        sequence = sequences[i]
        if not sequence:
            arrival.append(problem.idle_arrival(i))
            distance = problem.start_end_distance[i] if problem.start_end_distance else 0.0
        else:
            arrival.append(end[sequence[-1]] + problem.travel_to_end(i, sequence[-1]))
            distance = problem.start_distance[i][sequence[0]]
            distance += sum(
                problem.task_distance[a][b] for a, b in itertools.pairwise(sequence)
            )
            if problem.end_distance is not None:
                distance += problem.end_distance[sequence[-1]]
            cost += sum(problem.use_cost[i][k] for k in sequence)
        cost += distance * problem.travel_cost_per_m[i]
    return Schedule(
        coalitions=tuple(tuple(sorted(c)) for c in coalitions),
        sequences=tuple(tuple(s) for s in sequences),
        start=tuple(start),
        end=tuple(end),
        arrival=tuple(arrival),
        makespan=max(arrival, default=0.0) if problem.n_robots else 0.0,
        cost=cost,
    )


def pruned(problem: Problem, schedule: Schedule) -> Schedule:
    """The same plan with no spare member in any coalition, timed again.

    Never later: a robot dropped from a task goes straight on (see
    ``Problem.minimal``), so every time can only move earlier.
    """
    coalitions = [problem.minimal(k, c) for k, c in enumerate(schedule.coalitions)]
    if all(tuple(c) == s for c, s in zip(coalitions, schedule.coalitions, strict=True)):
        return schedule
    sequences = [
        tuple(k for k in s if i in coalitions[k]) for i, s in enumerate(schedule.sequences)
    ]
    again = timed(problem, coalitions, sequences)
    assert again is not None  # dropping members cannot make a cycle
    return again
