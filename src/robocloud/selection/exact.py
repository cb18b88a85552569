"""The exact optimizer: the true Pareto front of docs/model.md, beyond the thesis.

The thesis searches coalitions with MOPSO (Algorithm 4) and accepts that "the
solution may not be the best among all solutions". This module returns the
true front over all filtered candidates, so it is both the quality reference
for MOPSO and the better answer wherever it is fast.

How: an epsilon-constraint sweep over T. T is a maximum, so "T <= tau" only
says which robots may be used: a prefix of the candidates in time order.
For a size limit n, the sweep starts with every robot allowed, asks
:mod:`robocloud.selection.covering` for the cheapest coalitions of at most n
robots (every tie), keeps the fastest of them, then allows only robots
strictly faster than it and asks again, until no coalition is left or the
cheapest one breaks max_cost. Each answer is the cheapest coalition for its
time limit, so the points found are the (T, C) front for sizes up to n.

Sizes: the first sweep takes n = the largest useful coalition. A later sweep
with a smaller n would only differ where a point used more than n robots, so
the next sweep takes n = (the largest size seen) - 1, until a sweep finds
nothing. The union of the sweeps holds the whole (T, C, N) front: a front
point of size N is on the (T, C) front of sizes up to N, which the sweep
that covered N found. The cost of each step grows with the number of
capability classes and the coalition's size, not with the product of the
counts; how many steps there are is the front's size, measured in
benchmarks/.

Before that, dominance pruning removes robots that no Pareto-optimal
coalition can hold (see ``prune``), which is what makes 100,000 robots cheap.

A deadline can cut the sweep. The result then holds every point found so
far and a certified bound (``Bound``): every feasible coalition is matched by
a found one that is at most ``time`` seconds slower, ``cost`` dearer and
``size`` robots larger.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from robocloud.domain import Coalition
from robocloud.domain.numeric import ABS_TOL, REL_TOL
from robocloud.selection.budget import NO_DEADLINE, Deadline
from robocloud.selection.covering import CoverResult, CoverSolver
from robocloud.selection.pareto import pareto_front
from robocloud.selection.problem import BoolArray, CoalitionProblem, IntArray

_BLOCK = 128
# Dominance pruning compares each class with its superset classes; past this
# many classes it is skipped (the covering step's own per-class pruning still
# applies), so a fleet with every capability combination stays linear.
PRUNE_CLASSES = 256
# The robot ids the found coalitions may hold in total before the sweep stops
# as if its budget had run out: memory stays bounded whatever the counts.
MAX_FOUND_MEMBERS = 2_000_000
# Robots a one-robot task's skyline may leave for the front's rule (see
# ``one_robot_front``); past it the sweep is the cheaper way.
SKYLINE_MAX = 64


def _tolerance(value: float) -> float:
    return max(ABS_TOL, REL_TOL * abs(value))


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
    keep = keep[problem.uses[keep].any(axis=1)] if keep.size else keep
    if keep.size == 0:
        return keep.astype(np.int64)
    limit = problem.largest_useful_coalition
    order = keep[
        np.lexsort(
            (np.array(problem.ids, dtype=object)[keep], problem.cost[keep], problem.time[keep])
        )
    ]
    uses = problem.uses[order]
    classes, member = capability_classes(uses)
    if len(classes) > PRUNE_CLASSES or limit < 1:
        return np.asarray(order, dtype=np.int64)
    cost = problem.cost[order]
    margin = _tolerance(problem.max_cost)
    survives = np.zeros(order.size, dtype=bool)
    for m, mask in enumerate(classes):
        supersets = np.flatnonzero(uses[:, mask].all(axis=1))
        own = member[supersets] == m
        if supersets.size <= limit:
            survives[supersets[own]] = True
            continue
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
            # ``running`` holds the limit smallest so far, partitioned: the
            # limit-th smallest at its end, no full sort needed.
            kth[b] = running[limit - 1]
            merged = np.concatenate((running, block_smallest[b]))
            running = np.partition(merged, limit - 1)[:limit]
        dominated = kth[np.arange(c.size) // _BLOCK] < c - margin
        survives[supersets[own & ~dominated]] = True
    return np.asarray(order[survives], dtype=np.int64)


def capability_classes(uses: BoolArray) -> tuple[BoolArray, IntArray]:
    """``np.unique(uses, axis=0, return_inverse=True)``: the distinct rows, sorted, and each
    row's class.

    Rows of up to 62 capabilities are packed into integers first (the first
    capability the most significant bit, so the integers sort as the rows
    do): sorting integers is much faster than sorting rows
    (benchmarks/results/design-notes.md, packed-classes).
    """
    k = uses.shape[1]
    if k > 62:
        classes, member = np.unique(uses, axis=0, return_inverse=True)
        return classes, member.reshape(-1)
    shifts = np.arange(k - 1, -1, -1, dtype=np.int64)
    codes = uses.astype(np.int64) @ (np.int64(1) << shifts)
    distinct, member = np.unique(codes, return_inverse=True)
    classes = ((distinct[:, None] >> shifts) & 1).astype(bool)
    return classes, member.reshape(-1)


@dataclass(frozen=True)
class Bound:
    """How far a found front can be from the true one, per objective.

    Every feasible coalition is matched by a found coalition that is at most
    ``time`` seconds slower, ``cost`` dearer and ``size`` robots larger (an
    additive epsilon-dominance). All zero (up to the tolerance) when the
    front is exact.
    """

    time: float
    cost: float
    size: int

    @property
    def exact(self) -> bool:
        return self.time <= ABS_TOL and self.cost <= ABS_TOL and self.size == 0


EXACT = Bound(0.0, 0.0, 0)


@dataclass(frozen=True)
class ExactOutcome:
    """The front found; ``complete`` when it is the whole true front.

    ``bound`` is None only when the search was cut before any feasible
    coalition was found: then nothing is known but the lack of time.
    """

    front: list[Coalition]
    complete: bool
    bound: Bound | None
    steps: int  # covering problems solved
    nodes: int  # branch-and-bound nodes over all of them


def lower_bounds(problem: CoalitionProblem, robots: IntArray) -> tuple[float, int]:
    """(T, N) no feasible coalition of ``robots`` can go below; cheap and sound.

    T: every capability k needs need_k carriers, so T is at least the
    need_k-th smallest t_i among the carriers of k. N: at least the largest
    count, and at least the fewest robots whose capability counts add up to
    the sum of the counts (one robot brings each of its capabilities once).
    """
    uses = problem.uses[robots]
    need = problem.need
    fastest = 0.0
    for k, q in enumerate(need.tolist()):
        carriers = np.sort(problem.time[robots[uses[:, k]]])
        if carriers.size < q:
            return math.inf, problem.largest_useful_coalition + 1
        fastest = max(fastest, float(carriers[q - 1]))
    brought = np.sort(uses.sum(axis=1))[::-1]
    reach = np.cumsum(brought)
    total = int(need.sum())
    fewest = int(np.searchsorted(reach, total, side="left")) + 1
    return fastest, max(fewest, int(need.max(initial=0)))


def exact_search(
    problem: CoalitionProblem,
    survivors: IntArray | None = None,
    deadline: Deadline = NO_DEADLINE,
) -> ExactOutcome:
    """The Pareto front (docs/model.md) of all of ``problem``'s candidates, within ``deadline``."""
    keep = prune(problem) if survivors is None else survivors
    largest = problem.largest_useful_coalition
    if keep.size == 0 or largest < 1:
        return ExactOutcome([], True, EXACT, 0, 0)
    if int(problem.need.sum()) == 1:
        front = one_robot_front(problem, keep)
        if front is not None:
            return ExactOutcome(front, True, EXACT, 1, 0)
    solver = CoverSolver(problem, keep, deadline)
    sweep = _Sweep(problem, solver, deadline)
    return sweep.run(largest, keep)


def one_robot_front(problem: CoalitionProblem, keep: IntArray) -> list[Coalition] | None:
    """The front of a task one robot can do (one capability, needed once); None if not cheap.

    Every Pareto-optimal coalition is then one robot: a second one only adds
    time, cost and one to N. So the front is the (T, C) skyline of the single
    robots that bring the capability within max_cost, which is what the
    sweep would find, without its covering machinery (benchmarks/results/design-notes.md,
    skyline).

    The skyline's last step is the front's own rule, one robot at a time.
    When more than ``SKYLINE_MAX`` robots are left for it (robots alike in
    T and C, within the tolerance), the sweep is cheaper, and None says so:
    10,000 such robots took 0.86 s here and 0.03 s in the sweep.
    """
    bring = problem.uses[keep][:, problem.need > 0].any(axis=1)
    robots = keep[bring & (problem.cost[keep] <= problem.max_cost + _tolerance(problem.max_cost))]
    if robots.size == 0:
        return []
    # In (T, C) order, a robot dearer than every faster-or-as-fast one before
    # it is dominated; the few left go through the front's own rule.
    order = robots[np.lexsort((problem.cost[robots], problem.time[robots]))]
    cost = problem.cost[order]
    cheapest_before = np.minimum.accumulate(cost)
    slack = np.maximum(ABS_TOL, REL_TOL * np.abs(cheapest_before))
    left = order[cost <= cheapest_before + slack]
    if left.size > SKYLINE_MAX:
        return None
    return pareto_front(problem.coalition([i]) for i in left)


def exact_front(problem: CoalitionProblem, survivors: IntArray | None = None) -> list[Coalition]:
    """The whole Pareto front, however long it takes."""
    return exact_search(problem, survivors).front


class _Sweep:
    def __init__(self, problem: CoalitionProblem, solver: CoverSolver, deadline: Deadline):
        self.problem = problem
        self.solver = solver
        self.deadline = deadline
        self.found: list[Coalition] = []
        self.members = 0
        self.steps = 0
        self.nodes = 0

    def _affordable(self, cost: float) -> bool:
        return cost <= self.problem.max_cost + _tolerance(cost)

    def _keep(self, result: CoverResult, fastest: float | None) -> tuple[float, int]:
        """Record the fastest cheapest coalitions of ``result``: (their T, largest N)."""
        solver = self.solver
        times = [solver.fastest(x) for x in result.ties]
        limit = min(times) if fastest is None else fastest
        largest = 0
        for x, t in zip(result.ties, times, strict=True):
            if t > limit + _tolerance(limit):
                continue
            members = solver.coalition(x, limit)
            if members is None:
                continue
            coalition = self.problem.coalition(members)
            if not self._affordable(coalition.cost):
                continue
            self.found.append(coalition)
            self.members += coalition.size
            largest = max(largest, coalition.size)
        return limit, largest

    def run(self, largest: int, keep: IntArray) -> ExactOutcome:
        size_limit = largest
        previous_top = 0
        # The steps of the last sweep: a sweep with a smaller size limit
        # repeats them for as long as their answers fit that limit (their ties
        # of at most n robots are then exactly its ties), and only solves
        # afresh from the first step where they no longer do.
        history: list[CoverResult] = []
        while size_limit >= 1:
            self.solver.allow_all()
            top = 0
            last_time: float | None = None
            replay, history = history, []
            while True:
                if self.deadline.expired() or self.members >= MAX_FOUND_MEMBERS:
                    return self._cut(keep, last_time, previous_top, None)
                result = self._replayed(replay, len(history), size_limit)
                if result is None:
                    replay = []
                    result = self.solver.solve(size_limit)
                    self.steps += 1
                    self.nodes += result.nodes
                if result.status == "cut":
                    return self._cut(keep, last_time, previous_top, result)
                if result.status == "infeasible" or not self._affordable(result.cost):
                    break
                history.append(result)
                last_time, biggest = self._keep(result, None)
                top = max(top, biggest)
                self.solver.allow_faster_than(last_time)
            if top == 0:
                break
            previous_top = top
            size_limit = top - 1
        return ExactOutcome(pareto_front(self.found), True, EXACT, self.steps, self.nodes)

    @staticmethod
    def _replayed(replay: list[CoverResult], step: int, size_limit: int) -> CoverResult | None:
        """The earlier sweep's answer at this step, narrowed to ``size_limit``, if it holds."""
        if step >= len(replay):
            return None
        earlier = replay[step]
        ties = tuple(x for x in earlier.ties if int(x.sum()) <= size_limit)
        if not ties:
            return None
        return CoverResult("optimal", earlier.cost, ties, earlier.cost, 0)

    def _cut(
        self,
        keep: IntArray,
        last_time: float | None,
        previous_top: int,
        partial: CoverResult | None,
    ) -> ExactOutcome:
        """The front found so far and its certified distance from the true one.

        Say the sweep with size limit n was cut. A feasible coalition S of
        more than n robots was allowed at some step of an earlier, complete
        sweep, whose answer is no dearer, at most the tolerance slower and
        no larger. One of at most n robots allowed at a finished step of this
        sweep is matched the same way, except in size. One allowed at the
        step that was cut costs at least as much as the last answer of this
        sweep, which is then at most (its T - the least T of any coalition)
        slower; with no answer yet in this sweep, the earlier sweep covers S
        again, or else the best coalition the cut step found does, with its
        gap to the step's lower bound. In size, every found coalition is at
        most (its N - the least N of any coalition) larger.
        """
        problem = self.problem
        least_time, least_size = lower_bounds(problem, keep)
        slower = 0.0
        dearer = 0.0
        if last_time is not None:
            slower = max(0.0, last_time - least_time)
        elif previous_top == 0:
            # The first sweep, cut at its first step.
            if partial is not None and partial.ties and self._affordable(partial.cost):
                t, _ = self._keep(partial, None)
                slower = max(0.0, t - least_time)
                dearer = max(0.0, partial.cost - partial.lower_bound)
            else:
                front = pareto_front(self.found)
                return ExactOutcome(front, False, None, self.steps, self.nodes)
        if partial is not None and partial.ties and self._affordable(partial.cost):
            self._keep(partial, None)
        front = pareto_front(self.found)
        larger = max((c.size for c in front), default=0) - least_size
        bound = Bound(slower, dearer, max(0, larger))
        return ExactOutcome(front, False, bound, self.steps, self.nodes)


@dataclass(frozen=True)
class Cover:
    """A cheapest feasible coalition, as far as a bounded search could tell.

    ``members`` are robot indices, None when none was found; ``proven`` says
    the search finished, so None means no feasible coalition exists and a
    coalition is a cheapest one.
    """

    members: IntArray | None
    proven: bool


def cheapest(
    problem: CoalitionProblem,
    survivors: IntArray | None = None,
    deadline: Deadline = NO_DEADLINE,
    node_limit: int | None = None,
) -> Cover:
    """A cheapest feasible coalition, searched within ``deadline`` and ``node_limit`` nodes."""
    keep = prune(problem) if survivors is None else survivors
    largest = problem.largest_useful_coalition
    if keep.size == 0 or largest < 1:
        return Cover(None, True)
    solver = CoverSolver(problem, keep, deadline)
    result = solver.solve(largest, node_limit)
    proven = result.status != "cut"
    if not result.ties or not (
        result.cost <= problem.max_cost + _tolerance(result.cost)
    ):
        # A cut search's incumbent may still be dearer than a cheaper cover.
        return Cover(None, proven)
    coalitions = [solver.coalition(x) for x in result.ties]
    best = min((m for m in coalitions if m is not None), key=lambda m: problem.coalition(m).robots)
    return Cover(best, proven)


def cheapest_cover(problem: CoalitionProblem, survivors: IntArray | None = None) -> IntArray | None:
    """A cheapest feasible coalition (robot indices), or None when none exists."""
    return cheapest(problem, survivors).members
