"""Lower bounds on the makespan that need no search.

The anytime method cannot prove its plan optimal; these bounds say how far
from optimal it can be at most (the gap). Each holds for every plan:

- **Path bound.** Task k cannot start before, for each capability it needs,
  some robot bringing it has driven there from its start (``reach[k]``), nor
  before its predecessors have ended; it then lasts at least the shortest
  work any robot would put in, and after it some robot still drives to the
  end place, or a successor still has to be done. The longest such chain is a
  bound.
- **Load bound.** Each robot's arrival is at least the length of its route
  (drives and work, waits left out), so the makespan is at least their mean:
  every task needs at least ``fewest[k]`` members, each of whom has driven
  there (at least the nearest other place, at the fastest speed) and works
  there at least the shortest work; and in a benchmark instance every robot
  ends with a drive to the end depot.
"""

from __future__ import annotations

import itertools
import math

from robocloud.planning.problem import Problem


def fewest_members(problem: Problem, k: int) -> int:
    """At most the fewest robots that can cover task ``k`` (exact for up to 3 among
    up to 60 able robots)."""
    need = problem.need[k]
    least = max(need.values())
    able = [i for i in range(problem.n_robots) if problem.useful[i][k]]
    for size in range(least, 4):
        if size > 1 and len(able) > 60:
            return size  # no smaller group covers: still a bound, without the pairs
        for group in itertools.combinations(able, size):
            if problem.covers(k, group):
                return size
    return max(least, 3)


def lower_bound(problem: Problem) -> float:
    m, n = problem.n_tasks, problem.n_robots
    if m == 0:
        return max((problem.idle_arrival(i) for i in range(n)), default=0.0)
    fastest = max(problem.speed)
    shortest = [
        min(problem.work[i][k] for i in range(n) if problem.useful[i][k]) for k in range(m)
    ]
    reach = [
        max(
            min(
                problem.travel_from_start(i, k)
                for i in range(n)
                if c in problem.brings[i]
            )
            for c in problem.need[k]
        )
        for k in range(m)
    ]
    order = problem.topological_order()
    assert order is not None
    before = problem.predecessors()
    after: list[list[int]] = [[] for _ in range(m)]
    for j, k in problem.precedence:
        after[j].append(k)
    earliest = list(reach)
    for k in order:
        for j in before[k]:
            earliest[k] = max(earliest[k], earliest[j] + shortest[j])
    leave = [
        0.0 if problem.end_distance is None else problem.end_distance[k] / fastest
        for k in range(m)
    ]
    tail = list(leave)
    for k in reversed(order):
        for s in after[k]:
            tail[k] = max(tail[k], shortest[s] + tail[s])
    path = max(earliest[k] + shortest[k] + tail[k] for k in range(m))
    # Load bound.
    into = []
    for k in range(m):
        nearest = min(
            [problem.task_distance[j][k] for j in range(m) if j != k]
            + [problem.start_distance[i][k] for i in range(n)]
        )
        into.append(nearest / fastest)
    load = sum(fewest_members(problem, k) * (into[k] + shortest[k]) for k in range(m))
    if problem.start_end_distance is not None:
        # Every robot of a benchmark instance ends with a drive to the end depot.
        load += sum(
            min([problem.idle_arrival(i)] + [problem.travel_to_end(i, k) for k in range(m)])
            for i in range(n)
        )
    return max(path, load / n, 0.0) if math.isfinite(path) else 0.0
