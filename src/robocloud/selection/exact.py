"""The exact optimizer: the true Pareto front of MODEL.md, beyond the thesis.

The thesis searches coalitions with MOPSO (Algorithm 4) and accepts that "the
solution may not be the best among all solutions". This module returns the
true front over all filtered candidates, so it is both the quality reference
for MOPSO and the better answer wherever it is fast.

How: T is a maximum, C and N are sums, and coverage only counts up to each
required count. Taking robots in order of their time t_i, the robot taken last
fixes T of every coalition it closes. A dynamic program over (size, capped
coverage) keeps the cheapest partial coalition for each pair; each robot
extends every kept partial coalition once (a 0/1 knapsack), and a coalition
that reaches full coverage is a front candidate with T = t_i.

Before that, dominance pruning removes robots that no Pareto-optimal
coalition can hold (see ``prune``), which is what makes 100,000 robots cheap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from robocloud.domain import Coalition
from robocloud.domain.numeric import ABS_TOL, REL_TOL, isclose, less
from robocloud.selection.pareto import pareto_front
from robocloud.selection.problem import CoalitionProblem, IntArray

_BLOCK = 128


def _tolerance(value: float) -> float:
    return max(ABS_TOL, REL_TOL * abs(value))


def masks_of(problem: CoalitionProblem) -> IntArray:
    """Each candidate's U_i as a bit mask over the required capabilities."""
    bits = np.left_shift(1, np.arange(len(problem.capabilities), dtype=np.int64))
    return np.asarray(problem.uses.astype(np.int64) @ bits, dtype=np.int64)


def within_thresholds(problem: CoalitionProblem) -> IntArray:
    """Candidates whose own t_i and c_i fit the task's thresholds.

    A robot slower than max_time or dearer than max_cost makes every
    coalition holding it infeasible.
    """
    ok = (problem.time <= problem.max_time + _tolerance(problem.max_time)) & (
        problem.cost <= problem.max_cost + _tolerance(problem.max_cost)
    )
    return np.flatnonzero(ok)


def prune(problem: CoalitionProblem) -> IntArray:
    """The candidates that some Pareto-optimal coalition may hold, sorted by (t, c, id).

    Robot j is dropped when at least L = ``largest_useful_coalition`` other
    robots each bring every capability j brings, take no longer
    (t_r <= t_j) and cost strictly less (c_r < c_j beyond the tolerance of
    any feasible C). A coalition S holding j has at most L - 1 other members,
    so one of those robots is outside S; swapping it in keeps coverage, N
    and T (no longer), and lowers C beyond the tolerance: S is dominated.
    Counting uses robots in earlier blocks of the time order only, which
    prunes a little less than possible and never too much.
    """
    keep = within_thresholds(problem)
    if keep.size == 0:
        return keep
    limit = problem.largest_useful_coalition
    order = keep[
        np.lexsort(
            (np.array(problem.ids, dtype=object)[keep], problem.cost[keep], problem.time[keep])
        )
    ]
    masks = masks_of(problem)[order]
    cost = problem.cost[order]
    margin = _tolerance(problem.max_cost)
    survives = np.zeros(order.size, dtype=bool)
    for mask in np.unique(masks):
        supersets = np.flatnonzero((masks & mask) == mask)
        own = masks[supersets] == mask
        c = cost[supersets]
        n_blocks = -(-c.size // _BLOCK)
        padded = np.full(n_blocks * _BLOCK, np.inf)
        padded[: c.size] = c
        blocks = padded.reshape(n_blocks, _BLOCK)
        k = min(limit, _BLOCK)
        block_smallest = np.sort(np.partition(blocks, k - 1, axis=1)[:, :k], axis=1)
        # kth[b]: the limit-th smallest cost among blocks before b.
        kth = np.full(n_blocks, np.inf)
        running = np.full(limit, np.inf)
        for b in range(n_blocks):
            kth[b] = running[limit - 1]
            merged = np.concatenate((running, block_smallest[b]))
            running = np.sort(np.partition(merged, limit - 1)[:limit])
        dominated = kth[np.arange(c.size) // _BLOCK] < c - margin
        survives[supersets[own & ~dominated]] = True
    return np.asarray(order[survives], dtype=np.int64)


@dataclass(frozen=True)
class _Coverage:
    """Capped coverage vectors encoded as integers in a mixed radix."""

    need: tuple[int, ...]
    stride: tuple[int, ...]
    states: int

    @classmethod
    def of(cls, need: IntArray) -> _Coverage:
        stride, states = [], 1
        for q in need:
            stride.append(states)
            states *= int(q) + 1
        return cls(tuple(int(q) for q in need), tuple(stride), states)

    @property
    def full(self) -> int:
        return self.states - 1

    def transitions(self, mask: int) -> IntArray:
        """For every state, the state after adding a robot with ``mask``."""
        state = np.arange(self.states, dtype=np.int64)
        after = np.zeros_like(state)
        for k, (q, stride) in enumerate(zip(self.need, self.stride, strict=True)):
            digit = (state // stride) % (q + 1)
            if mask >> k & 1:
                digit = np.minimum(digit + 1, q)
            after += digit * stride
        return after


def exact_work(problem: CoalitionProblem, survivors: IntArray | None = None) -> int:
    """The dynamic program's size: robots x coverage states x sizes."""
    if survivors is None:
        survivors = prune(problem)
    states = _Coverage.of(problem.need).states
    return int(survivors.size) * states * (problem.largest_useful_coalition + 1)


def exact_front(problem: CoalitionProblem, survivors: IntArray | None = None) -> list[Coalition]:
    """The Pareto front of MODEL.md over all of ``problem``'s candidates."""
    if survivors is None:
        survivors = prune(problem)
    coverage = _Coverage.of(problem.need)
    limit = problem.largest_useful_coalition
    # Ties between equal costs go to the lexicographically smaller sorted id
    # list; comparing tuples of id ranks compares those lists.
    id_rank = {i: r for r, i in enumerate(sorted(survivors.tolist(), key=lambda i: problem.ids[i]))}
    masks = masks_of(problem)
    transitions: dict[int, IntArray] = {}
    # (size, coverage state) -> (cost, id ranks sorted, robot indices)
    table: dict[tuple[int, int], tuple[float, tuple[int, ...], tuple[int, ...]]] = {
        (0, 0): (0.0, (), ())
    }
    best_upto = np.full(limit + 1, np.inf)  # cheapest full coalition of size <= n so far
    found: list[Coalition] = []
    for i in survivors.tolist():
        mask = int(masks[i])
        step = transitions.get(mask)
        if step is None:
            step = transitions[mask] = coverage.transitions(mask)
        c_i, r_i = float(problem.cost[i]), id_rank[i]
        closed: dict[int, tuple[float, tuple[int, ...], tuple[int, ...]]] = {}
        for (n, state), (cost, ranks, members) in list(table.items()):
            if n >= limit:
                continue
            new_cost = cost + c_i
            if new_cost > problem.max_cost + _tolerance(problem.max_cost):
                continue
            entry = (new_cost, tuple(sorted((*ranks, r_i))), (*members, i))
            target = int(step[state])
            if target == coverage.full:
                _keep_better(closed, n + 1, entry)
            elif target != state and n + 1 < limit:
                # A robot that adds no coverage is redundant, and a partial
                # coalition at the size limit can never be completed.
                _keep_better(table, (n + 1, target), entry)
        for n, (cost, _, members) in sorted(closed.items()):
            if cost > best_upto[n] + _tolerance(best_upto[n] if np.isfinite(best_upto[n]) else 0):
                continue  # an earlier, no slower coalition is cheaper and no larger
            best_upto[n:] = np.minimum(best_upto[n:], cost)
            found.append(problem.coalition(members))
    return pareto_front(found)


def _keep_better(
    table: dict[tuple[int, int], tuple[float, tuple[int, ...], tuple[int, ...]]]
    | dict[int, tuple[float, tuple[int, ...], tuple[int, ...]]],
    key: object,
    entry: tuple[float, tuple[int, ...], tuple[int, ...]],
) -> None:
    old = table.get(key)  # type: ignore[call-overload]
    if old is None or less(entry[0], old[0]) or (isclose(entry[0], old[0]) and entry[1] < old[1]):
        table[key] = entry  # type: ignore[index]


def cheapest_cover(problem: CoalitionProblem, survivors: IntArray | None = None) -> IntArray | None:
    """A cheapest feasible coalition (robot indices), or None when none exists.

    The same dynamic program without the front: vectorised over all states,
    so it stays fast where the exact front would be too much work. The
    pool stage uses it as a witness that the pool hides no feasible coalition.
    """
    if survivors is None:
        survivors = prune(problem)
    coverage = _Coverage.of(problem.need)
    limit = problem.largest_useful_coalition
    masks = masks_of(problem)
    cost = np.full((limit + 1, coverage.states), np.inf)
    cost[0, 0] = 0.0
    node = np.full((limit + 1, coverage.states), -1, dtype=np.int64)
    node_robot: list[int] = []
    node_parent: list[int] = []
    transitions: dict[int, IntArray] = {}
    for i in survivors.tolist():
        mask = int(masks[i])
        step = transitions.get(mask)
        if step is None:
            step = transitions[mask] = coverage.transitions(mask)
        candidate = cost[:-1] + problem.cost[i]
        # Scatter to the target states; several sources may share a target,
        # so take the best source per target first.
        best = np.full_like(candidate, np.inf)
        np.minimum.at(best, (slice(None), step), candidate)  # type: ignore[arg-type]
        improved = best < cost[1:]
        if not improved.any():
            continue
        # The source of each improved target: the one whose candidate equals the best.
        rows, targets = np.nonzero(improved)
        before = node.copy()  # sources are read as they were before this robot
        for n, target in zip(rows.tolist(), targets.tolist(), strict=True):
            sources = np.flatnonzero((step == target) & (candidate[n] == best[n, target]))
            node_robot.append(i)
            node_parent.append(int(before[n, sources[0]]))
            node[n + 1, target] = len(node_robot) - 1
        cost[1:] = np.where(improved, best, cost[1:])
    full = cost[:, coverage.full]
    n = int(np.argmin(full))
    if not np.isfinite(full[n]) or full[n] > problem.max_cost + _tolerance(problem.max_cost):
        return None
    members, at = [], int(node[n, coverage.full])
    while at >= 0:
        members.append(node_robot[at])
        at = node_parent[at]
    return np.array(sorted(members), dtype=np.int64)
