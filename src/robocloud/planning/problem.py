"""The planning problem in numbers: what every solver of this package reads.

A robocloud mission (``mission.py``) and an MRTA-Benchmark instance
(``mrta.py``) are both translated into a :class:`Problem`; the solvers
(``cpsat.py``, ``lns.py``, ``greedy.py``) never see either input shape.

Robots are ``0..N-1``, tasks ``0..M-1`` (an MRTA instance's task ``k`` is
index ``k - 1``: its depots are not tasks here). Robot ``i`` starts at its own
place at time 0; it needs ``travel(i, a, b) = distance(a, b) / speed_i``
between two places. Task ``k`` needs, for each capability ``c`` of
``need[k]``, ``need[k][c]`` distinct members that bring ``c``; it lasts the
longest ``work[i][k]`` over its members (the same for every member when the
task has a fixed duration).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

Priority = Literal["balanced", "time", "cost"]


@dataclass(frozen=True)
class Problem:
    robot_ids: tuple[str, ...]
    task_ids: tuple[str, ...]
    # Capability names robot i brings.
    brings: tuple[frozenset[str], ...]
    # Per task: capability -> how many distinct members must bring it.
    need: tuple[dict[str, int], ...]
    # Distances: task to task (M x M), robot start to task (N x M),
    # task to end (M; None: no end place), robot start to end (N; None likewise).
    task_distance: tuple[tuple[float, ...], ...]
    start_distance: tuple[tuple[float, ...], ...]
    end_distance: tuple[float, ...] | None
    start_end_distance: tuple[float, ...] | None
    speed: tuple[float, ...]
    # work[i][k]: how long task k takes when robot i is a member (math.inf: i brings
    # nothing k needs, so it is never a member).
    work: tuple[tuple[float, ...], ...]
    # What robot i's membership of task k costs (its capabilities used there).
    use_cost: tuple[tuple[float, ...], ...]
    travel_cost_per_m: tuple[float, ...]
    precedence: tuple[tuple[int, int], ...]
    priority: Priority = "time"
    max_time: float | None = None
    useful: tuple[tuple[bool, ...], ...] = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(
            self,
            "useful",
            tuple(
                tuple(math.isfinite(self.work[i][k]) for k in range(self.n_tasks))
                for i in range(self.n_robots)
            ),
        )

    @property
    def n_robots(self) -> int:
        return len(self.robot_ids)

    @property
    def n_tasks(self) -> int:
        return len(self.task_ids)

    def travel_between(self, i: int, a: int, b: int) -> float:
        return self.task_distance[a][b] / self.speed[i]

    def travel_from_start(self, i: int, k: int) -> float:
        return self.start_distance[i][k] / self.speed[i]

    def travel_to_end(self, i: int, k: int) -> float:
        return 0.0 if self.end_distance is None else self.end_distance[k] / self.speed[i]

    def idle_arrival(self, i: int) -> float:
        """When robot ``i`` is done if it does no task: the drive to the end, or 0."""
        if self.start_end_distance is None:
            return 0.0
        return self.start_end_distance[i] / self.speed[i]

    def duration(self, k: int, members: Sequence[int]) -> float:
        return max(self.work[i][k] for i in members)

    def covers(self, k: int, members: Sequence[int]) -> bool:
        return all(
            sum(1 for i in members if c in self.brings[i]) >= n for c, n in self.need[k].items()
        )

    def minimal(self, k: int, members: Sequence[int]) -> tuple[int, ...]:
        """``members`` without spare ones: each left is needed to cover the task.

        Drops the members whose work on the task is longest first, so a
        shorter task is what dropping gains. A member dropped from a task
        leaves the rest of a schedule feasible: its route skips a place, and a
        straight line is never longer than a detour (triangle inequality).
        """
        kept = sorted(members, key=lambda i: (-self.work[i][k], i))
        for i in list(kept):
            rest = [j for j in kept if j != i]
            if rest and self.covers(k, rest):
                kept = rest
        return tuple(sorted(kept))

    def predecessors(self) -> tuple[tuple[int, ...], ...]:
        before: list[list[int]] = [[] for _ in range(self.n_tasks)]
        for j, k in self.precedence:
            before[k].append(j)
        return tuple(tuple(p) for p in before)

    def topological_order(self) -> tuple[int, ...] | None:
        """The tasks in an order that respects precedence (None: a cycle)."""
        before = self.predecessors()
        left = [len(p) for p in before]
        after: list[list[int]] = [[] for _ in range(self.n_tasks)]
        for j, k in self.precedence:
            after[j].append(k)
        ready = sorted(k for k in range(self.n_tasks) if left[k] == 0)
        order: list[int] = []
        while ready:
            k = ready.pop(0)
            order.append(k)
            for m in after[k]:
                left[m] -= 1
                if left[m] == 0:
                    ready.append(m)
            ready.sort()
        return tuple(order) if len(order) == self.n_tasks else None

    def uncoverable(self) -> tuple[int, str] | None:
        """The first task and capability too few robots bring, if any."""
        for k in range(self.n_tasks):
            for c, n in self.need[k].items():
                if sum(1 for b in self.brings if c in b) < n:
                    return k, c
        return None
