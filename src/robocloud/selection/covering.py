"""Cheapest covers by capability class: the search step of the exact optimizer.

Why one long file: the proof below is what makes the search correct (the
bound from the duals, the enumeration's budget), and the solver, the branch
and bound and the Lagrangian enumeration it speaks of share each node's
state; kept apart, a rule would stand away from its proof.

A candidate's *class* is the set of required capabilities it brings (its
U_i). Within a class robots differ only in t_i and c_i, so once the robots
allowed are fixed (in the exact optimizer: every robot no slower than a time
limit) the cheapest coalition with x_m robots of class m takes the x_m
cheapest of that class. What is left is a problem over the class counts x:

    minimise   F(x) = sum_m F_m(x_m)      (F_m: the x_m cheapest costs, convex)
    subject to sum over classes m that bring k of x_m >= need_k, for every k
               sum_m x_m <= n,   lo_m <= x_m <= hi_m (integers)

with hi_m at most cap_m, the largest need among class m's capabilities: in a
coalition from which no robot can be dropped (the only kind that can be
Pareto-optimal) a class with more robots than that holds a robot no count
needs. Its size grows with the number of classes and the coalition's size,
never with the product of the counts.

The search is a branch and bound on the class counts. At each node HiGHS
solves the linear relaxation (one model per search, warm-started: only
bounds change), and its row duals serve as Lagrange multipliers lambda_k (the
counts) and mu (the size). For any multipliers >= 0, every feasible x obeys

    F(x) = LB + sum_m dev_m(x_m) + sum_k lambda_k (cover_k(x) - need_k) + mu (n - sum_m x_m)

where LB is the Lagrangian bound of the node and dev_m(x) >= 0 is how far
F_m(x) - pi_m x lies above its least value over the node's range, pi_m being
the class's price (the multipliers of what it brings, less mu). Every term
after LB is non-negative, so *all* x whose cost is within a budget of LB are
found by enumerating the class counts whose deviations fit in that budget.
Where the relaxation is integral (almost always:
benchmarks/results/design-notes.md, integral-relaxation) the budget is
docs/model.md's tolerance: the enumeration then lists every tie, which the
tie rule (the smallest sorted id list) needs. Only where that list
would be long does the node branch. The bound is computed here from the
duals, so a slightly inexact dual from the solver weakens a bound and never
makes one wrong.

Within a class, costs are compared exactly (sorted by cost, then id): two
robots of one class whose costs differ by less than the tolerance but are
not equal count as different. The same tolerance still applies to totals.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from typing import Literal

import highspy
import numpy as np

from robocloud.domain.numeric import ABS_TOL, REL_TOL
from robocloud.selection.budget import NO_DEADLINE, Deadline
from robocloud.selection.problem import BoolArray, CoalitionProblem, FloatArray, IntArray

# DFS steps an enumeration may take before its node branches instead.
ENUMERATION_LIMIT = 4_000
# A search whose whole box holds at most this many count vectors lists them
# all at once instead (no LP): the thesis's 5-robot task is such a search.
GRID_LIMIT = 20_000
# A class total this close to an integer is that integer.
INTEGRAL = 1e-6

CoverStatus = Literal["optimal", "infeasible", "cut"]


def tolerance(value: float) -> float:
    return max(ABS_TOL, REL_TOL * abs(value))


@dataclass(frozen=True)
class CoverResult:
    """The cheapest class counts, or why there are none.

    ``ties`` holds every count vector whose cost is within docs/model.md's
    tolerance of ``cost`` (when ``status`` is optimal). ``lower_bound`` is a
    proven bound on the optimum: equal to ``cost`` when optimal, below it
    when the search was cut (by the deadline or a node limit), in which case
    ``ties`` holds the best found, if any.
    """

    status: CoverStatus
    cost: float
    ties: tuple[IntArray, ...]
    lower_bound: float
    nodes: int


class _Cut(Exception):
    """The deadline or the node limit ended the search."""


@dataclass
class _Relaxation:
    totals: FloatArray  # the LP's class totals
    lam: FloatArray
    mu: float


class CoverSolver:
    """Cheapest covers over the classes of ``robots`` (indices into ``problem``).

    The robots allowed can be narrowed by time (``allow_faster_than``) and
    reset (``allow_all``); each ``solve`` then answers for the robots allowed.
    """

    def __init__(
        self, problem: CoalitionProblem, robots: IntArray, deadline: Deadline = NO_DEADLINE
    ) -> None:
        self.problem = problem
        self.deadline = deadline
        self.need = problem.need.astype(np.int64)
        k = len(self.need)
        robots = np.asarray(robots, dtype=np.int64)
        robots = robots[problem.uses[robots].any(axis=1)] if robots.size else robots
        if robots.size:
            brings, member = np.unique(problem.uses[robots], axis=0, return_inverse=True)
            member = member.reshape(-1)
        else:
            brings, member = np.zeros((0, k), dtype=bool), np.zeros(0, dtype=np.int64)
        self.brings: BoolArray = brings
        self.brings_float = brings.astype(np.float64)
        need_of = np.where(brings, self.need[None, :], 0)
        self.cap: IntArray = need_of.max(axis=1, initial=0).astype(np.int64)
        ids = np.array(problem.ids, dtype=str)
        id_rank = np.empty(problem.size, dtype=np.int64)
        id_rank[np.argsort(ids, kind="stable")] = np.arange(problem.size)
        self.id_rank = id_rank
        columns: list[IntArray] = []
        # One sort groups the robots by class, however many classes there are.
        grouped = robots[np.argsort(member, kind="stable")]
        bounds = np.searchsorted(np.sort(member), np.arange(len(brings) + 1))
        for m in range(len(brings)):
            mine = grouped[bounds[m] : bounds[m + 1]]
            mine = _skyline(mine, problem.time, problem.cost, id_rank, int(self.cap[m]))
            columns.append(mine[np.lexsort((id_rank[mine], problem.cost[mine]))])
        self.classes = len(columns)
        sizes = np.array([c.size for c in columns], dtype=np.int64)
        self.start = np.concatenate(([0], np.cumsum(sizes))).astype(np.int64)
        self.column_robot: IntArray = (
            np.concatenate(columns) if columns else np.zeros(0, dtype=np.int64)
        )
        self.column_class = np.repeat(np.arange(self.classes), sizes)
        self.column_cost = problem.cost[self.column_robot]
        self.column_time = problem.time[self.column_robot]
        self.allowed = np.ones(self.column_robot.size, dtype=bool)
        self._costs: list[FloatArray] = []
        self._prefix: list[FloatArray] = []
        self._refresh(range(self.classes))
        self._highs: highspy._core._Highs | None = None

    # --- the robots allowed ------------------------------------------------

    def allow_all(self) -> None:
        self._set_allowed(np.ones_like(self.allowed))

    def allow_faster_than(self, limit: float) -> None:
        """Allow only robots strictly faster than ``limit`` beyond the tolerance."""
        t = self.column_time
        self._set_allowed(self.allowed & (t < limit - np.maximum(ABS_TOL, REL_TOL * limit)))

    @property
    def highs(self) -> highspy._core._Highs:
        """The LP, built when a search first needs it (small ones never do)."""
        if self._highs is None:
            self._highs = self._model()
            closed = np.flatnonzero(~self.allowed)
            if closed.size:
                self._highs.changeColsBounds(
                    int(closed.size), closed.astype(np.int32), np.zeros(closed.size),
                    np.zeros(closed.size),
                )
        return self._highs

    def _set_allowed(self, allowed: BoolArray) -> None:
        changed = np.flatnonzero(allowed != self.allowed)
        if changed.size == 0:
            return
        self.allowed = allowed
        if self._highs is not None:
            upper = allowed[changed].astype(np.float64)
            self._highs.changeColsBounds(
                int(changed.size), changed.astype(np.int32), np.zeros(changed.size), upper
            )
        self._refresh(np.unique(self.column_class[changed]).tolist())

    def _refresh(self, classes: range | list[int]) -> None:
        """Per class: the allowed columns in (cost, id) order, their costs and prefix sums."""
        if not self._costs:
            self._columns: list[IntArray] = [np.zeros(0, dtype=np.int64)] * self.classes
            self._costs = [np.zeros(0)] * self.classes
            self._prefix = [np.zeros(1)] * self.classes
            self._available = np.zeros(self.classes, dtype=np.int64)
        for m in classes:
            lo, hi = self.start[m], self.start[m + 1]
            columns = lo + np.flatnonzero(self.allowed[lo:hi])
            self._columns[m] = columns
            self._costs[m] = self.column_cost[columns]
            self._prefix[m] = np.concatenate(([0.0], np.cumsum(self._costs[m])))
            self._available[m] = columns.size

    def available(self) -> IntArray:
        """How many robots of each class are allowed."""
        return self._available

    # --- the linear relaxation ----------------------------------------------

    def _model(self) -> highspy._core._Highs:
        k, m = len(self.need), self.classes
        n_cols = int(self.column_robot.size)
        rows_per_class = [
            np.concatenate((np.flatnonzero(self.brings[c]), [k, k + 1 + c])).astype(np.int32)
            for c in range(m)
        ]
        per_column = [rows_per_class[c] for c in self.column_class.tolist()]
        counts = np.array([r.size for r in per_column], dtype=np.int32)
        lp = highspy.HighsLp()
        lp.num_col_ = n_cols
        lp.num_row_ = k + 1 + m
        lp.col_cost_ = self.column_cost.astype(np.float64)
        lp.col_lower_ = np.zeros(n_cols)
        lp.col_upper_ = np.ones(n_cols)
        inf = highspy.kHighsInf
        lp.row_lower_ = np.concatenate((self.need.astype(np.float64), np.zeros(1 + m)))
        lp.row_upper_ = np.concatenate(
            (np.full(k, inf), [float(self.cap.sum())], self.cap.astype(np.float64))
        )
        lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
        lp.a_matrix_.start_ = np.concatenate(([0], np.cumsum(counts))).astype(np.int32)
        lp.a_matrix_.index_ = (
            np.concatenate(per_column) if per_column else np.zeros(0, dtype=np.int32)
        )
        lp.a_matrix_.value_ = np.ones(int(counts.sum()))
        # The bare binding: the Python ``Highs`` class adds callback plumbing
        # that costs time on every one of the many small solves.
        highs = highspy._core._Highs()
        highs.setOptionValue("output_flag", False)
        highs.setOptionValue("threads", 1)
        highs.setOptionValue("presolve", "off")
        highs.passModel(lp)
        return highs

    def _relax(self, lo: IntArray, hi: IntArray, n: int) -> _Relaxation | None:
        """The LP over the node's box; None when it is infeasible."""
        k, m = len(self.need), self.classes
        rows = np.arange(k, k + 1 + m, dtype=np.int32)
        lower = np.concatenate(([0.0], lo.astype(np.float64)))
        upper = np.concatenate(([float(n)], hi.astype(np.float64)))
        # changeRowsBounds is in the binding but missing from its stubs.
        self.highs.changeRowsBounds(m + 1, rows, lower, upper)  # type: ignore[attr-defined]
        remaining = self.deadline.remaining()
        if remaining <= 0:
            raise _Cut
        # HiGHS's clock runs on across the solves of one model: its limit is
        # the time it has used so far plus what the deadline leaves.
        self.highs.setOptionValue("time_limit", self.highs.getRunTime() + min(remaining, 1e6))
        self.highs.run()
        status = self.highs.getModelStatus()
        if status == highspy.HighsModelStatus.kInfeasible:
            return None
        if status != highspy.HighsModelStatus.kOptimal:
            raise _Cut  # the time limit, or a numerical failure: stop, say so
        solution = self.highs.getSolution()
        column = np.asarray(solution.col_value, dtype=np.float64)
        dual = np.asarray(solution.row_dual, dtype=np.float64)
        totals = np.add.reduceat(column, self.start[:-1]) if m else np.zeros(0)
        return _Relaxation(totals, np.maximum(dual[:k], 0.0), max(-float(dual[k]), 0.0))

    # --- the search ------------------------------------------------------------

    def solve(self, n: int, node_limit: int | None = None) -> CoverResult:
        """The cheapest class counts with at most ``n`` robots, and every tie."""
        search = _Search(self, n, node_limit)
        return search.run()

    def cost_of(self, counts: IntArray) -> float:
        return float(sum(self._prefix[m][int(x)] for m, x in enumerate(counts) if x))

    def coalition(self, counts: IntArray, time_limit: float = math.inf) -> IntArray | None:
        """The smallest sorted id list among the cheapest coalitions with these
        counts whose robots are no slower than ``time_limit`` (within the
        tolerance); None when no cheapest one is that fast."""
        chosen: list[IntArray] = []
        limit = time_limit + tolerance(time_limit) if math.isfinite(time_limit) else math.inf
        for m in np.flatnonzero(counts).tolist():
            x = int(counts[m])
            columns = self._columns[m]
            cost = self._costs[m]
            boundary = cost[x - 1]
            # The cheapest x are every robot below the boundary cost and the
            # rest from those at it: the earliest ids among those fast enough.
            below = columns[: int(np.searchsorted(cost, boundary, side="left"))]
            if below.size == x and self.column_time[below].max() <= limit:
                chosen.append(self.column_robot[below])
                continue
            at = columns[below.size : int(np.searchsorted(cost, boundary, side="right"))]
            at = at[self.column_time[at] <= limit]
            if (self.column_time[below] > limit).any() or at.size < x - below.size:
                return None
            # Columns at one cost are in id order already.
            chosen += [self.column_robot[below], self.column_robot[at[: x - below.size]]]
        return np.sort(np.concatenate(chosen)) if chosen else np.zeros(0, dtype=np.int64)

    def fastest(self, counts: IntArray) -> float:
        """The least T over the cheapest coalitions with these counts."""
        worst = -math.inf
        for m in np.flatnonzero(counts).tolist():
            x = int(counts[m])
            columns = self._columns[m]
            cost = self._costs[m]
            boundary = cost[x - 1]
            first = int(np.searchsorted(cost, boundary, side="left"))
            last = int(np.searchsorted(cost, boundary, side="right"))
            times = self.column_time[columns[:last]]
            if first:
                worst = max(worst, float(times[:first].max()))
            if last - first == x - first or x == first:
                worst = max(worst, float(times[first:x].max(initial=-math.inf)))
            else:
                worst = max(worst, float(np.partition(times[first:], x - first - 1)[x - first - 1]))
        return worst


def _skyline(
    robots: IntArray, time: FloatArray, cost: FloatArray, id_rank: IntArray, cap: int
) -> IntArray:
    """The robots of one class that are among its ``cap`` cheapest at some time limit.

    A robot with at least ``cap`` class-mates no slower and earlier in (cost,
    id) order is never among the ``cap`` cheapest of the robots allowed, at
    any time limit that allows it.
    """
    if cap <= 0 or robots.size <= cap:
        return robots
    order = robots[np.lexsort((id_rank[robots], cost[robots], time[robots]))]
    key = np.lexsort((id_rank[order], cost[order]))
    rank = np.empty(order.size, dtype=np.int64)
    rank[key] = np.arange(order.size)
    heap: list[int] = []  # the cap best ranks seen so far, negated
    keep = np.zeros(order.size, dtype=bool)
    for j, r in enumerate(rank.tolist()):
        if len(heap) < cap:
            heapq.heappush(heap, -r)
            keep[j] = True
        elif r < -heap[0]:
            heapq.heapreplace(heap, -r)
            keep[j] = True
    return np.asarray(order[keep], dtype=np.int64)


class _Search:
    """One branch and bound: nodes are boxes lo <= x <= hi over the class counts."""

    def __init__(self, solver: CoverSolver, n: int, node_limit: int | None) -> None:
        self.s = solver
        self.n = n
        self.node_limit = node_limit
        self.best = math.inf
        self.found: dict[tuple[int, ...], float] = {}
        self.nodes = 0

    def _record(self, counts: IntArray) -> None:
        cost = self.s.cost_of(counts)
        if cost > self.best + tolerance(self.best if math.isfinite(self.best) else 0.0):
            return
        self.found[tuple(int(x) for x in counts)] = cost
        if cost < self.best:
            self.best = cost

    def _feasible(self, counts: IntArray) -> bool:
        cover = counts @ self.s.brings.astype(np.int64)
        return bool((cover >= self.s.need).all() and counts.sum() <= self.n)

    def run(self) -> CoverResult:
        s = self.s
        available = s.available()
        hi0 = np.minimum(np.minimum(s.cap, available), self.n)
        lo0 = np.zeros(s.classes, dtype=np.int64)
        if s.classes == 0 or ((hi0 @ s.brings.astype(np.int64)) < s.need).any():
            return CoverResult("infeasible", math.inf, (), math.inf, 0)
        if int(np.prod((hi0 + 1).astype(float))) <= GRID_LIMIT:
            return self._grid(hi0)
        stack: list[tuple[IntArray, IntArray, float]] = [(lo0, hi0, -math.inf)]
        try:
            while stack:
                lo, hi, parent = stack[-1]
                if parent > self.best + tolerance(self.best):
                    stack.pop()
                    continue
                if self.node_limit is not None and self.nodes >= self.node_limit:
                    raise _Cut
                self.nodes += 1
                children = self._node(lo, hi)
                stack.pop()
                stack += children
        except _Cut:
            bound = min([self.best] + [p for _, _, p in stack])
            return CoverResult("cut", self.best, self._ties(), bound, self.nodes)
        if not math.isfinite(self.best):
            return CoverResult("infeasible", math.inf, (), math.inf, self.nodes)
        return CoverResult("optimal", self.best, self._ties(), self.best, self.nodes)

    def _grid(self, hi: IntArray) -> CoverResult:
        """Every count vector of the box at once: feasible ones, their costs, the ties."""
        s = self.s
        counts = np.indices(tuple(int(h) + 1 for h in hi)).reshape(s.classes, -1).T
        cover = counts @ s.brings.astype(np.int64)
        counts = counts[(cover >= s.need).all(axis=1) & (counts.sum(axis=1) <= self.n)]
        if counts.size == 0:
            return CoverResult("infeasible", math.inf, (), math.inf, 0)
        cost = np.zeros(len(counts))
        for m in range(s.classes):
            cost += s._prefix[m][counts[:, m]]
        best = float(cost.min())
        ties = counts[cost <= best + tolerance(best)]
        ordered = sorted(tuple(int(v) for v in x) for x in ties)
        found = tuple(np.array(x, dtype=np.int64) for x in ordered)
        # The exact cost of the best, summed as ``cost_of`` sums it.
        exact = min(s.cost_of(x) for x in found)
        return CoverResult("optimal", exact, found, exact, 0)

    def _ties(self) -> tuple[IntArray, ...]:
        if not math.isfinite(self.best):
            return ()
        limit = self.best + tolerance(self.best)
        return tuple(
            np.array(x, dtype=np.int64) for x, cost in sorted(self.found.items()) if cost <= limit
        )

    def _node(self, lo: IntArray, hi: IntArray) -> list[tuple[IntArray, IntArray, float]]:
        """Bound one box; enumerate it when cheap, else return its two halves."""
        s = self.s
        relaxation = s._relax(lo, hi, self.n)
        if relaxation is None:
            return []
        lagrange = _Lagrange(s, lo, hi, self.n, relaxation.lam, relaxation.mu)
        bound = lagrange.bound
        if bound > self.best + tolerance(self.best):
            return []
        totals = relaxation.totals
        rounded = np.rint(totals).astype(np.int64)
        fractional = np.abs(totals - rounded) > INTEGRAL
        guess = rounded if not fractional.any() else np.ceil(totals - INTEGRAL).astype(np.int64)
        guess = np.clip(guess, lo, lagrange.upper)
        if self._feasible(guess):
            self._record(guess)
        if math.isfinite(self.best):
            budget = self.best + tolerance(self.best) - bound
            if lagrange.enumerate(budget, self):
                return []
        # Branch: on the most fractional class, else on the widest one left.
        if fractional.any():
            m = int(np.argmax(np.where(fractional, -np.abs(totals - rounded - 0.5), -np.inf)))
            split_low, split_high = math.floor(totals[m]), math.ceil(totals[m])
        else:
            width = np.where(lagrange.upper > lo, lagrange.upper - lo, -1)
            m = int(np.argmax(width))
            if width[m] <= 0:
                return []  # a single point, already recorded
            x = int(rounded[m])
            split_low, split_high = (x, x + 1) if x < lagrange.upper[m] else (x - 1, x)
        low_hi = lagrange.upper.copy()
        low_hi[m] = split_low
        high_lo = lo.copy()
        high_lo[m] = split_high
        near_high = totals[m] - split_low > 0.5
        low = (lo, low_hi, bound)
        high = (high_lo, lagrange.upper.copy(), bound)
        return [low, high] if near_high else [high, low]


class _Lagrange:
    """The Lagrangian bound of a box for given multipliers, and its enumeration."""

    def __init__(
        self, s: CoverSolver, lo: IntArray, hi: IntArray, n: int, lam: FloatArray, mu: float
    ) -> None:
        self.s, self.lo, self.n, self.lam, self.mu = s, lo, n, lam, mu
        price = s.brings_float @ lam - mu
        self.upper = np.minimum(hi, s.available())
        self.dev: list[FloatArray] = []
        bound = float(lam @ s.need) - mu * n
        for m in range(s.classes):
            a, b = int(lo[m]), int(self.upper[m])
            g = s._prefix[m][a : b + 1] - price[m] * np.arange(a, b + 1)
            least = float(g.min()) if g.size else math.inf
            bound += least
            self.dev.append(g - least)
        self.bound = bound

    def enumerate(self, budget: float, search: _Search) -> bool:
        """Record every feasible x of the box with cost <= bound + budget.

        False, having recorded nothing, when the counts to try could number
        more than ENUMERATION_LIMIT (the caller then branches).
        """
        s = self.s
        if budget < 0:
            return True
        slack = budget + tolerance(budget)
        options = [self.lo[m] + np.flatnonzero(d <= slack) for m, d in enumerate(self.dev)]
        free = sorted((m for m in range(s.classes) if options[m].size > 1),
                      key=lambda m: options[m].size)
        leaves = 1
        for m in free:
            leaves *= int(options[m].size)
            if leaves > ENUMERATION_LIMIT:
                return False
        counts = np.array([int(o[0]) for o in options], dtype=np.int64)
        brings = s.brings.astype(np.int64)
        # Plain Python numbers below: the vectors are short and visited often.
        need = s.need.tolist()
        lam = self.lam.tolist()
        mu, n = self.mu, self.n
        free_brings = [brings[m].tolist() for m in free]
        free_options = [
            [(int(x), float(self.dev[m][int(x) - int(self.lo[m])])) for x in options[m]]
            for m in free
        ]
        # What the free classes from i on can still add: per capability, in size.
        most = [[0] * len(need) for _ in range(len(free) + 1)]
        fewest = [0] * (len(free) + 1)
        largest = [0] * (len(free) + 1)
        for i in range(len(free) - 1, -1, -1):
            top = int(options[free[i]].max())
            most[i] = [a + top * b for a, b in zip(most[i + 1], free_brings[i], strict=True)]
            fewest[i] = fewest[i + 1] + int(options[free[i]].min())
            largest[i] = largest[i + 1] + top
        fixed = [m for m in range(s.classes) if options[m].size == 1]
        base_counts = counts.copy()
        base_counts[free] = 0
        cover0 = (base_counts @ brings).tolist()
        used0 = float(sum(self.dev[m][int(counts[m]) - int(self.lo[m])] for m in fixed))

        def visit(i: int, used: float, cover: list[int], size: int) -> None:
            if size + fewest[i] > n:
                return
            excess = 0.0
            for c, q, extra, weight in zip(cover, need, most[i], lam, strict=True):
                if c + extra < q:
                    return
                if c > q:
                    excess += weight * (c - q)
            # Coverage only grows from here, and the size's slack only shrinks.
            if used + excess + mu * max(0, n - size - largest[i]) > slack:
                return
            if i == len(free):
                search._record(counts.copy())
                return
            m = free[i]
            bring = free_brings[i]
            for x, d in free_options[i]:
                if used + d > slack:
                    continue
                counts[m] = x
                visit(i + 1, used + d, [c + x * b for c, b in zip(cover, bring, strict=True)],
                      size + x)

        visit(0, used0, cover0, int(base_counts.sum()))
        return True
