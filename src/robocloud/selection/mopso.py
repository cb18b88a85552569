"""MOPSO (thesis Algorithm 4) with Algorithm 5's evaluation, as a binary PSO over a pool.

A particle is a coalition: a boolean vector over the pool (the best-ranked
candidates the pool stage picked). Algorithm 4's steps, as done here:

- steps 2-4: positions are feasible coalitions (the thesis's "coalitions that
  met the task requirements"): a few greedy ones (fastest, cheapest, fewest
  robots, cheapest under several time caps, ...) and the rest random, each
  repaired; velocities random. The thesis's "Target" is the task's location,
  already folded into each robot's t_i by :mod:`robocloud.selection.problem`.
- step 5 and Algorithm 5: ``CoalitionProblem.evaluate`` gives T = max t_i,
  C = sum c_i and N = |S| for the whole swarm at once.
- step 6: the feasible, non-dominated positions go to REP
  (:mod:`robocloud.selection.mopso_repository`).
- steps 7-8: pBEST[i] = par[i].
- steps 9-17: each iteration, the velocity update
  ``vel = W*vel + c1*r1*(pBEST - par) + c2*r2*(REP[h] - par)`` with velocity
  clamping, the binary position update of Kennedy and Eberhart
  (``par = rand < sigmoid(vel)``), Coello's mutation with a rate that falls
  over the iterations, the repair, the evaluation, REP's update and pBEST's
  update (replaced when the new position dominates it, kept when it
  dominates the new position, else one of the two at random).
- step 18: the thresholds are checked with ``CoalitionProblem.feasible``; only
  feasible positions enter REP, and pBEST compares by constrained dominance.

The repair keeps every particle covering the required capabilities and
minimal: a robot whose removal keeps every count met only adds time, cost and
one robot, so no Pareto-optimal coalition holds one (see
``CoalitionProblem.largest_useful_coalition``). Each particle has its own
preference over the robots (a random blend of rank, time, cost, cost per
capability and breadth) that the repair uses to add and drop robots; the
blends spread the swarm along the front.

Everything random comes from ``numpy.random.default_rng(settings.seed)``: the
same seed gives the same coalitions.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from robocloud.domain import Coalition
from robocloud.domain.numeric import margin_array
from robocloud.errors import InvalidInput
from robocloud.selection.budget import NO_DEADLINE, Deadline
from robocloud.selection.mopso_repository import Repository, dominates_rows
from robocloud.selection.pareto import pareto_front
from robocloud.selection.problem import CoalitionProblem

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.int64]

# Kennedy and Eberhart's binary PSO clamps velocities to +-4: sigmoid(4) is
# 0.98, so a bit can always still flip.
MAX_VELOCITY = 4.0
# How much randomness the repair's preference order gets, against a spread
# of 1 between the best and the worst robot.
REPAIR_NOISE = 0.15
# The share of particles that step along the time-cost trade-off after each
# iteration's repair (``_Swarm._polish``).
TIGHTEN_SHARE = 0.3
# Coello's mutation: the share of particles mutated at iteration t is
# (1 - t / (iterations * mutation_rate)) ** MUTATION_DECAY.
MUTATION_DECAY = 1.5
# The robot features a particle's preference blends, each scaled to [0, 1],
# larger worse: rank in the pool, t_i, c_i, c_i per capability brought, and
# how few required capabilities the robot brings.
RANK, TIME, COST, COST_PER_CAPABILITY, NARROWNESS = range(5)
FEATURES = 5


@dataclass(frozen=True)
class MopsoSettings:
    """MOPSO's parameters; the defaults suit pools of up to a few dozen robots.

    ``leader`` is the thesis's rule (``random``: a member of REP at random)
    or Coello's adaptive grid roulette (``grid``). ``mutation_rate`` is the
    share of the iterations during which mutation acts.
    """

    swarm_size: int = 40
    iterations: int = 40
    repository_size: int = 100
    leader: Literal["random", "grid"] = "random"
    grid_divisions: int = 7
    mutation_rate: float = 0.5
    inertia: float = 0.9
    c1: float = 1.5
    c2: float = 1.5
    seed: int = 0

    def __post_init__(self) -> None:
        whole = "must be a whole number of at least"
        checks = (
            ("swarm_size", _whole(self.swarm_size, 1), f"{whole} 1"),
            ("iterations", _whole(self.iterations, 0), f"{whole} 0"),
            ("repository_size", _whole(self.repository_size, 1), f"{whole} 1"),
            ("leader", self.leader in ("random", "grid"), "must be 'random' or 'grid'"),
            ("grid_divisions", _whole(self.grid_divisions, 1), f"{whole} 1"),
            ("mutation_rate", _between(self.mutation_rate, 0.0, 1.0), "must be between 0 and 1"),
            ("inertia", _between(self.inertia, 0.0, 1.0), "must be between 0 and 1"),
            ("c1", _between(self.c1, 0.0, math.inf), "must be a number of at least 0"),
            ("c2", _between(self.c2, 0.0, math.inf), "must be a number of at least 0"),
            ("seed", _whole(self.seed, 0), f"{whole} 0"),
        )
        for field, ok, sentence in checks:
            if not ok:
                raise InvalidInput(f"MOPSO's {field} {sentence}.", field=field)


def _whole(value: object, least: int) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= least


def _between(value: object, low: float, high: float) -> bool:
    return (
        isinstance(value, int | float)
        and not isinstance(value, bool)
        and math.isfinite(value)
        and low <= value <= high
    )


@dataclass(frozen=True)
class MopsoOutcome:
    """REP's front; ``complete`` unless the deadline stopped the iterations early."""

    front: list[Coalition]
    complete: bool
    iterations: int


def mopso(
    problem: CoalitionProblem, pool: IntArray, settings: MopsoSettings = MopsoSettings()
) -> list[Coalition]:
    """Algorithm 4 over the robots of ``pool`` (indices into ``problem``, best first).

    Returns REP's feasible coalitions, mutually non-dominated and sorted as
    :func:`robocloud.selection.pareto.pareto_front` sorts them; empty when no
    coalition of the pool is feasible.
    """
    return mopso_search(problem, pool, settings).front


def mopso_search(
    problem: CoalitionProblem,
    pool: IntArray,
    settings: MopsoSettings = MopsoSettings(),
    *,
    seeds: Sequence[IntArray] = (),
    deadline: Deadline = NO_DEADLINE,
) -> MopsoOutcome:
    """``mopso`` with seed coalitions and a deadline.

    ``seeds`` are coalitions (indices into ``problem``, within ``pool``) that
    replace some of the random initial particles (steps 2-3), e.g. the
    cheap covers of :func:`robocloud.selection.pool.seed_covers`. The
    deadline is checked between iterations; REP as it stands is the answer.
    """
    pool = _checked_pool(problem, pool)
    # A robot slower or dearer on its own than the thresholds is in no
    # feasible coalition; one that brings nothing is in no minimal one.
    time_tol = margin_array(problem.time[pool])
    cost_tol = margin_array(problem.cost[pool])
    useful = (
        (problem.time[pool] <= problem.max_time + time_tol)
        & (problem.cost[pool] <= problem.max_cost + cost_tol)
        & problem.uses[pool].any(axis=1)
    )
    pool = pool[useful]
    if len(pool) == 0 or (problem.uses[pool].sum(axis=0) < problem.need).any():
        # Only the empty coalition is left, feasible when nothing is required.
        empty = np.zeros((1, problem.size), dtype=bool)
        front = [problem.coalition([])] if problem.feasible(empty)[0] else []
        return MopsoOutcome(front, True, 0)
    position = {int(r): j for j, r in enumerate(pool)}
    rows = np.zeros((len(seeds), len(pool)), dtype=bool)
    for row, seed in zip(rows, seeds, strict=True):
        inside = [position[int(r)] for r in seed if int(r) in position]
        if len(inside) == len(seed):
            row[inside] = True
    rows = rows[rows.any(axis=1)]
    swarm = _Swarm(problem.subproblem(pool), settings, rows)
    done = 0
    for iteration in range(settings.iterations):  # step 9
        if deadline.expired():
            break
        swarm.next(iteration)
        done += 1
    front = pareto_front(problem.coalition(pool[np.flatnonzero(row)]) for row in swarm.rep.members)
    return MopsoOutcome(front, done == settings.iterations, done)


def _checked_pool(problem: CoalitionProblem, pool: IntArray) -> IntArray:
    indices = np.asarray(pool)
    if indices.ndim != 1 or (indices.size and not np.issubdtype(indices.dtype, np.integer)):
        raise InvalidInput("The MOPSO pool must be a list of candidate indices.", field="pool")
    indices = indices.astype(np.int64)
    if indices.size and (indices.min() < 0 or indices.max() >= problem.size):
        raise InvalidInput(
            f"The MOPSO pool names a candidate outside 0..{problem.size - 1}.", field="pool"
        )
    _, first = np.unique(indices, return_index=True)
    return np.asarray(indices[np.sort(first)], dtype=np.int64)


class _Swarm:
    """One run of Algorithm 4 on the pool's subproblem: set up (steps 2-8),
    then ``next`` once per iteration (steps 10-18)."""

    def __init__(
        self, problem: CoalitionProblem, settings: MopsoSettings, seeds: BoolArray | None = None
    ) -> None:
        self.problem = problem
        self.settings = settings
        self.rng = np.random.default_rng(settings.seed)
        self.need = problem.need
        self.brings = np.ascontiguousarray(problem.uses.T)  # (K, m)
        # Counts as float matrix products: BLAS, and exact at these sizes.
        self.uses_float = problem.uses.astype(np.float64)
        self.brings_float = np.ascontiguousarray(self.uses_float.T)
        self.features = self._features()
        # The pool's robots by class (the set of required capabilities they
        # bring), each class cheapest first: what ``_polish`` picks from.
        _, member = np.unique(problem.uses, axis=0, return_inverse=True)
        member = member.reshape(-1)
        self.class_order = np.lexsort((problem.cost, member))
        self.class_of = member[self.class_order]
        self.class_starts = np.flatnonzero(np.r_[True, self.class_of[1:] != self.class_of[:-1]])
        self.class_of = np.cumsum(np.r_[False, self.class_of[1:] != self.class_of[:-1]])
        self.ordered_time = problem.time[self.class_order]
        self.rep = Repository(problem.size, settings.repository_size, settings.grid_divisions)
        # Steps 2-4: positions, each particle's preference, velocities.
        self.position, self.preference = self._initial_swarm()
        if seeds is not None and len(seeds):
            # Seed coalitions take the places of the last random particles.
            take = min(len(seeds), max(self.settings.swarm_size // 2, 1))
            self.position[-take:] = seeds[:take]
        self.velocity = self.rng.uniform(-1.0, 1.0, size=self.position.shape)
        # Step 5 (Algorithm 5) and step 6: the feasible non-dominated go to REP.
        objectives, violation = self._evaluate(self.position)
        feasible = violation == 0
        self.rep.update(self.position[feasible], objectives[feasible], self.rng)
        # Steps 7-8: pBEST[i] = par[i].
        self.best = self.position.copy()
        self.best_objectives = objectives
        self.best_violation = violation

    def _features(self) -> FloatArray:
        p = self.problem
        brought = p.uses.sum(axis=1).astype(np.float64)
        raw = np.empty((FEATURES, p.size))
        raw[RANK] = np.arange(p.size)
        raw[TIME] = p.time
        raw[COST] = p.cost
        raw[COST_PER_CAPABILITY] = p.cost / brought
        raw[NARROWNESS] = -brought
        low = raw.min(axis=1, keepdims=True)
        span = raw.max(axis=1, keepdims=True) - low
        return np.asarray(np.divide(raw - low, span, out=np.zeros_like(raw), where=span > 0))

    def _initial_swarm(self) -> tuple[BoolArray, FloatArray]:
        """Steps 2-3: greedy coalitions, then random ones, all repaired."""
        size = self.settings.swarm_size
        m = self.problem.size
        seeds, seed_penalty = self._greedy_preferences()
        seeds, seed_penalty = seeds[: size // 2 or 1], seed_penalty[: size // 2 or 1]
        g = len(seeds)
        preference = np.concatenate((seeds, self.rng.dirichlet(np.ones(FEATURES), size=size - g)))
        start = np.zeros((size, m), dtype=bool)
        density = self.rng.uniform(0.0, 0.5, size=(size - g, 1))
        start[g:] = self.rng.random((size - g, m)) < density
        penalty = np.zeros((size, m))
        penalty[:g] = seed_penalty
        noise = np.zeros(size)
        noise[g:] = REPAIR_NOISE
        repaired = self._repair(start, preference, penalty, noise)
        return self._polish(repaired, np.zeros(size, dtype=bool)), preference

    def _greedy_preferences(self) -> tuple[FloatArray, FloatArray]:
        """Preferences (and penalties on robots past a cap) of the greedy seeds.

        One seed per feature alone (the best ranked, the fastest, the
        cheapest, the cheapest per capability, the fewest robots), then the
        cheapest under a few time caps and the fastest under a few cost caps,
        which spread the seeds along the time-cost trade-off.
        """
        p = self.problem
        rows: list[FloatArray] = []
        penalties: list[FloatArray] = []
        none = np.zeros(p.size)
        for feature in range(FEATURES):
            rows.append(np.eye(FEATURES)[feature])
            penalties.append(none)
        for share in (0.2, 0.4, 0.6, 0.8):
            for capped, wanted in ((TIME, COST), (TIME, COST_PER_CAPABILITY), (COST, TIME)):
                cap = np.quantile(self.features[capped], share)
                rows.append(np.eye(FEATURES)[wanted])
                penalties.append((self.features[capped] > cap).astype(np.float64))
        return np.array(rows), np.array(penalties)

    def next(self, iteration: int) -> None:
        """Steps 10-18 for the whole swarm: one iteration of the while loop."""
        s = self.settings
        rng = self.rng
        size, m = self.position.shape
        if len(self.rep):
            leader = self.rep.members[self.rep.leaders(size, s.leader, rng)]
        else:
            # No feasible coalition yet: follow a random particle's pBEST.
            leader = self.best[rng.integers(0, size, size=size)]
        x = self.position.astype(np.float64)
        # Velocity update, clamped; the binary position update.
        self.velocity = np.clip(
            s.inertia * self.velocity
            + s.c1 * rng.random((size, m)) * (self.best - x)
            + s.c2 * rng.random((size, m)) * (leader - x),
            -MAX_VELOCITY,
            MAX_VELOCITY,
        )
        position = rng.random((size, m)) < 1.0 / (1.0 + np.exp(-self.velocity))
        position = self._mutate(position, iteration)
        position = self._repair(
            position, self.preference, np.zeros((size, m)), np.full(size, REPAIR_NOISE)
        )
        tighten = np.asarray(rng.random(size) < TIGHTEN_SHARE)
        self.position = self._polish(position, tighten)
        # Algorithm 5 and step 18.
        objectives, violation = self._evaluate(self.position)
        feasible = violation == 0
        self.rep.update(self.position[feasible], objectives[feasible], rng)
        self._update_best(objectives, violation)

    def _mutate(self, position: BoolArray, iteration: int) -> BoolArray:
        """Coello's mutation: early on most particles flip several bits, later none."""
        s = self.settings
        span = s.iterations * s.mutation_rate
        if iteration >= span:
            return position
        share = (1.0 - iteration / span) ** MUTATION_DECAY
        size, m = position.shape
        flips = max(1, round(share * self.problem.largest_useful_coalition))
        mutated = self.rng.random(size) < share
        flip = np.zeros((size, m), dtype=bool)
        # Drawn with replacement: a bit drawn twice flips once.
        flip[np.arange(size)[:, None], self.rng.integers(0, m, size=(size, flips))] = True
        return np.asarray(position ^ (mutated[:, None] & flip))

    def _polish(self, position: BoolArray, tighten: BoolArray) -> BoolArray:
        """Each particle keeps how many robots it has of each class, but takes the
        cheapest robots of that class no slower than its T; those in ``tighten``
        take them strictly faster than their T, when enough are.

        A class is a set of required capabilities; robots of one class are
        interchangeable for coverage, so coverage and N stay, and T and C get
        no worse: a polished particle weakly dominates the one it was. A
        tightened particle steps along the time-cost trade-off instead (T
        down, C up), as the exact optimizer's sweep does.
        """
        time, _, _ = self.problem.evaluate(position)
        margin = margin_array(time)
        loose = time + margin
        order, starts, of = self.class_order, self.class_starts, self.class_of
        held = np.add.reduceat(position[:, order].astype(np.int64), starts, axis=1)
        wanted = held[:, of]

        def pick(limit: FloatArray) -> tuple[BoolArray, BoolArray]:
            # All classes at once: a running count restarted at each class's start.
            eligible = self.ordered_time[None, :] <= limit[:, None]
            running = np.cumsum(eligible, axis=1)
            before = np.concatenate((np.zeros((len(limit), 1), dtype=np.int64), running), axis=1)
            rank = running - before[:, starts][:, of]
            enough = (np.add.reduceat(eligible, starts, axis=1) >= held).all(axis=1)
            return eligible & (rank <= wanted), np.asarray(enough)

        chosen, enough = pick(np.where(tighten, time - margin, loose))
        short = ~enough
        if short.any():
            # Too few faster robots: those particles are polished without tightening.
            chosen[short] = pick(loose)[0][short]
        polished = np.zeros_like(position)
        polished[:, order] = chosen
        return polished

    def _repair(
        self,
        position: BoolArray,
        preference: FloatArray,
        penalty: FloatArray,
        noise: FloatArray,
    ) -> BoolArray:
        """Cover every required capability, then drop redundant robots.

        The robots are taken in the particle's preference order, its members
        before the others, and a robot is kept when it brings a capability
        still short of its count; then, while some robot can go without
        breaking a count, the least preferred such robot goes (the slowest or
        dearest, as the particle weighs them).
        """
        size, m = position.shape
        worth = preference @ self.features
        key = worth + penalty + noise[:, None] * self.rng.random((size, m)) + 3.0 * ~position
        order = np.argsort(key, axis=1, kind="stable")
        taken = np.zeros((size, m), dtype=bool)
        for capability, need in enumerate(self.need):
            brought = self.brings[capability][order]
            taken |= brought & (np.cumsum(brought, axis=1) <= need)
        repaired = np.zeros_like(position)
        np.put_along_axis(repaired, order, taken, axis=1)
        counts = repaired @ self.uses_float
        while True:
            # A robot is held by a capability it brings whose count is at its need.
            held = ((counts <= self.need) @ self.brings_float) > 0
            redundant = repaired & ~held
            some = np.flatnonzero(redundant.any(axis=1))
            if len(some) == 0:
                return repaired
            worst = np.argmax(np.where(redundant[some], worth[some], -np.inf), axis=1)
            repaired[some, worst] = False
            counts[some] -= self.uses_float[worst]

    def _evaluate(self, position: BoolArray) -> tuple[FloatArray, FloatArray]:
        """Algorithm 5 for the whole swarm, and step 18's thresholds.

        Returns (T, C, N) per particle and how far it is past the thresholds
        (0 when feasible).
        """
        p = self.problem
        time, cost, size = p.evaluate(position)
        feasible = p.feasible(position)
        over = (
            np.maximum(cost - p.max_cost, 0.0) / max(p.max_cost, 1.0)
            + np.maximum(size - p.max_robots, 0)
            + np.maximum(time - p.max_time, 0.0) / max(p.max_time, 1.0)
        )
        violation = np.where(feasible, 0.0, np.maximum(over, 1e-12))
        return np.column_stack((time, cost, size.astype(np.float64))), violation

    def _update_best(self, objectives: FloatArray, violation: FloatArray) -> None:
        """pBEST: replaced when the new position dominates (constrained), kept
        when dominated, chosen at random when neither dominates."""
        old_objectives, old_violation = self.best_objectives, self.best_violation
        both_feasible = (violation == 0) & (old_violation == 0)
        new_wins = np.where(
            both_feasible, dominates_rows(objectives, old_objectives), violation < old_violation
        )
        old_wins = np.where(
            both_feasible, dominates_rows(old_objectives, objectives), old_violation < violation
        )
        coin = self.rng.random(len(violation)) < 0.5
        replace = new_wins | (~old_wins & coin)
        self.best = np.where(replace[:, None], self.position, self.best)
        self.best_objectives = np.where(replace[:, None], objectives, old_objectives)
        self.best_violation = np.where(replace, violation, old_violation)
