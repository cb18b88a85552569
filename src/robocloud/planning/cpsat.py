"""The exact model of a mission, solved by OR-Tools CP-SAT.

Variables, for task k and robot i (only where i brings something k needs):

- ``x[i,k]``: robot i is a member of task k's coalition;
- ``start[k]``, ``end[k] = start[k] + duration[k]``: shared by every member,
  so the members start together by construction; an optional interval per
  member, present with ``x[i,k]``, and no two intervals of a robot overlap
  (implied by the routes below; it helps the search);
- per robot, a circuit (``AddCircuit``) through node 0, its start and end,
  and the tasks it does: arc ``0 -> k`` gives ``start[k] >= travel(start_i, k)``,
  arc ``j -> k`` gives ``start[k] >= end[j] + travel(j, k)``, arc ``k -> 0``
  gives ``makespan >= end[k] + travel(k, end)``, the loop ``k -> k`` means i
  skips k, and ``0 -> 0`` that i does nothing (``makespan >= travel(start_i, end)``);
- for each capability c a task needs n of: ``sum x[i,k] over i bringing c >= n``;
- precedence ``(j, k)``: ``start[k] >= end[j]``;
- when the task's duration depends on its members: ``duration[k] >= work[i][k]``
  wherever ``x[i,k]``.

CP-SAT works on integers: times are multiplied by ``scale`` and every travel
and work time rounded *up*, so a plan of the model is a plan of the problem.
The plan's own times are then computed again in floating point
(``schedule.timed``); a robot's route has at most ``2M + 1`` rounded legs and
tasks, so the optimum of the rounded model is at most ``(2M + 1) / scale``
above the true one, which the lower bound subtracts.

Objective (docs/model.md): minimise the makespan; then, where robots cost
something, the total cost with the makespan bounded (``cost``: by the
mission's ``max_time``; ``time``: by the best makespan; ``balanced``: by
``BALANCED_SLACK`` times it).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass

from ortools.sat.python import cp_model

from robocloud.planning.problem import Problem
from robocloud.planning.schedule import Schedule, earliest, pruned, timed

# Balanced: the cheapest plan at most this much longer than the fastest one found.
BALANCED_SLACK = 1.1
# The largest scaled horizon: CP-SAT's domains are 64-bit, but its linear
# relaxation is happier with smaller numbers.
MAX_SCALED = 10**9
MAX_SCALE = 10**5
COST_SCALE = 100  # costs to hundredths


@dataclass(frozen=True)
class Outcome:
    schedule: Schedule | None
    lower_bound: float  # on the makespan; 0 when unknown
    optimal: bool  # the makespan is proven minimal (up to the rounding)
    infeasible: bool  # proven: no plan at all (within max_time)


def choose_scale(horizon: float) -> int:
    """A power of ten that keeps ``horizon`` times it within MAX_SCALED."""
    if horizon <= 0:
        return MAX_SCALE
    power = math.floor(math.log10(MAX_SCALED / horizon))
    return int(min(MAX_SCALE, 10 ** max(0, power)))


class MissionModel:
    """The CP-SAT model of one problem; built once, solved in phases."""

    def __init__(
        self,
        problem: Problem,
        horizon: float,
        scale: int | None = None,
        *,
        fixed: Mapping[int, Sequence[int]] | None = None,
        allowed: Collection[int] | None = None,
    ) -> None:
        """``fixed``: robots whose route is given (the large-neighbourhood search
        keeps them); the others may do only the tasks of ``allowed`` (None: any).
        With neither, the whole problem, and alike robots' symmetry broken."""
        self.problem = problem
        self.fixed = dict(fixed or {})
        self.fixed_members: list[list[int]] = [[] for _ in range(problem.n_tasks)]
        for i, sequence in self.fixed.items():
            for k in sequence:
                self.fixed_members[k].append(i)
        self.scale = scale or choose_scale(horizon)
        self.model = cp_model.CpModel()
        p, model = problem, self.model
        # Rounding up may put the hint's own plan a little above its float makespan.
        big = self._up(horizon) + 2 * p.n_tasks + 2
        if p.max_time is not None:
            big = min(big, self._up(p.max_time) + 2 * p.n_tasks + 1)
        self.horizon = big
        self.x: dict[tuple[int, int], cp_model.IntVar] = {}
        self.arcs: dict[tuple[int, int, int], cp_model.IntVar] = {}  # (i, from, to), 0 = depot
        self.idle: dict[int, cp_model.IntVar] = {}
        # When each robot is done; the makespan is the latest.
        self.arrival = [model.new_int_var(0, big, f"arrival{i}") for i in range(p.n_robots)]
        self.start = [model.new_int_var(0, big, f"s{k}") for k in range(p.n_tasks)]
        self.end = [model.new_int_var(0, big, f"e{k}") for k in range(p.n_tasks)]
        self.makespan = model.new_int_var(0, big, "makespan")
        cost_terms: list[cp_model.LinearExprT] = []
        durations = []
        variable = []
        for k in range(p.n_tasks):
            works = sorted({self._up(p.work[i][k]) for i in range(p.n_robots) if p.useful[i][k]})
            if not works:
                works = [0]
            duration = (
                model.new_constant(works[0])
                if len(works) == 1
                else model.new_int_var(works[0], works[-1], f"d{k}")
            )
            durations.append(duration)
            variable.append(len(works) > 1)
            model.add(self.end[k] == self.start[k] + duration)
            model.new_interval_var(self.start[k], duration, self.end[k], f"task{k}")
        for k in range(p.n_tasks):
            for i in self.fixed_members[k]:
                if variable[k]:
                    model.add(durations[k] >= self._up(p.work[i][k]))
        for i, sequence in self.fixed.items():
            self._follow(i, sequence)
        for i in range(p.n_robots):
            if i in self.fixed:
                continue
            intervals = []
            mine = [
                k for k in range(p.n_tasks)
                if p.useful[i][k] and (allowed is None or k in allowed)
            ]
            circuit: list[tuple[int, int, cp_model.LiteralT]] = []
            # The route's driving and working time, waits left out: a linear bound on
            # the robot's arrival that the LP relaxation sees (the circuit alone is weak).
            route: list[cp_model.LinearExprT] = []
            idle = model.new_bool_var(f"idle{i}")
            self.idle[i] = idle
            circuit.append((0, 0, idle))
            arrival = self.arrival[i]
            model.add(self.makespan >= arrival)
            model.add(arrival >= self._up(p.idle_arrival(i))).only_enforce_if(idle)
            per_m = p.travel_cost_per_m[i] * COST_SCALE
            if p.start_end_distance is not None:
                cost_terms.append(idle * round(per_m * p.start_end_distance[i]))
            for k in mine:
                x = model.new_bool_var(f"x{i}_{k}")
                self.x[i, k] = x
                intervals.append(
                    model.new_optional_interval_var(
                        self.start[k], durations[k], self.end[k], x, f"r{i}t{k}"
                    )
                )
                cost_terms.append(x * round(p.use_cost[i][k] * COST_SCALE))
                if variable[k]:
                    model.add(durations[k] >= self._up(p.work[i][k])).only_enforce_if(x)
                circuit.append((k + 1, k + 1, ~x))
                first = model.new_bool_var(f"a{i}_0_{k}")
                self.arcs[i, 0, k + 1] = first
                circuit.append((0, k + 1, first))
                model.add(self.start[k] >= self._up(p.travel_from_start(i, k))).only_enforce_if(
                    first
                )
                cost_terms.append(first * round(per_m * p.start_distance[i][k]))
                route.append(first * self._up(p.travel_from_start(i, k)))
                route.append(x * self._up(p.work[i][k]))
                last = model.new_bool_var(f"a{i}_{k}_0")
                self.arcs[i, k + 1, 0] = last
                circuit.append((k + 1, 0, last))
                model.add(
                    arrival >= self.end[k] + self._up(p.travel_to_end(i, k))
                ).only_enforce_if(last)
                route.append(last * self._up(p.travel_to_end(i, k)))
                if p.end_distance is not None:
                    cost_terms.append(last * round(per_m * p.end_distance[k]))
                for j in mine:
                    if j == k:
                        continue
                    arc = model.new_bool_var(f"a{i}_{j}_{k}")
                    self.arcs[i, j + 1, k + 1] = arc
                    circuit.append((j + 1, k + 1, arc))
                    model.add(
                        self.start[k] >= self.end[j] + self._up(p.travel_between(i, j, k))
                    ).only_enforce_if(arc)
                    cost_terms.append(arc * round(per_m * p.task_distance[j][k]))
                    route.append(arc * self._up(p.travel_between(i, j, k)))
            route.append(idle * self._up(p.idle_arrival(i)))
            model.add(arrival >= sum(route))
            model.add_circuit(circuit)
            model.add_no_overlap(intervals)
        for k in range(p.n_tasks):
            for capability, count in p.need[k].items():
                already = sum(1 for i in self.fixed_members[k] if capability in p.brings[i])
                model.add(
                    sum(self.x[i, k] for i in range(p.n_robots) if capability in p.brings[i]
                        and (i, k) in self.x)
                    >= count - already
                )
            # A redundant bound: someone must drive from k to the end.
            if p.end_distance is not None:
                fastest = max(p.speed[i] for i in range(p.n_robots))
                model.add(self.makespan >= self.end[k] + self._up(p.end_distance[k] / fastest))
            else:
                model.add(self.makespan >= self.end[k])
        for j, k in p.precedence:
            model.add(self.start[k] >= self.end[j])
        self.twins = _twins(p) if fixed is None and allowed is None else []
        self._break_symmetry()
        self.cost = sum(cost_terms) if cost_terms else 0
        self.has_cost = any(
            c for c in p.travel_cost_per_m
        ) or any(c for row in p.use_cost for c in row)

    def _follow(self, i: int, sequence: Sequence[int]) -> None:
        """A kept robot: its route is fixed, only its times may move."""
        p, model = self.problem, self.model
        arrival = self.arrival[i]
        model.add(self.makespan >= arrival)
        if not sequence:
            model.add(arrival >= self._up(p.idle_arrival(i)))
            return
        model.add(self.start[sequence[0]] >= self._up(p.travel_from_start(i, sequence[0])))
        for j, k in itertools.pairwise(sequence):
            model.add(self.start[k] >= self.end[j] + self._up(p.travel_between(i, j, k)))
        model.add(arrival >= self.end[sequence[-1]] + self._up(p.travel_to_end(i, sequence[-1])))

    def _break_symmetry(self) -> None:
        """Of two robots alike in everything, the first does the lowest-numbered task.

        Valid because swapping two such robots' whole routes changes no time
        and no cost: so for each task k, the second robot may do k only if the
        first does some task numbered k or lower (``canonical`` puts any plan
        in this form).
        """
        for group in self.twins:
            for twin, i in itertools.pairwise(group):
                for k in range(self.problem.n_tasks):
                    if (i, k) in self.x:
                        self.model.add(
                            self.x[i, k]
                            <= sum(self.x[twin, j] for j in range(k + 1) if (twin, j) in self.x)
                        )

    def canonical(self, schedule: Schedule) -> Schedule:
        """The same plan with alike robots' routes swapped as ``_break_symmetry`` wants."""
        rename = list(range(self.problem.n_robots))
        for group in self.twins:
            routes = sorted(group, key=lambda i: min(schedule.sequences[i], default=1 << 30))
            for new, old in zip(group, routes, strict=True):
                rename[old] = new
        if rename == list(range(self.problem.n_robots)):
            return schedule
        sequences: list[tuple[int, ...]] = [()] * self.problem.n_robots
        for old, new in enumerate(rename):
            sequences[new] = schedule.sequences[old]
        coalitions = [tuple(sorted(rename[i] for i in c)) for c in schedule.coalitions]
        again = timed(self.problem, coalitions, sequences)
        assert again is not None
        return again

    def _up(self, value: float) -> int:
        return math.ceil(value * self.scale - 1e-9)

    @property
    def slack(self) -> float:
        """How far above the true optimum the rounded model's optimum may be."""
        return (2 * self.problem.n_tasks + 1) / self.scale

    def hint(self, schedule: Schedule) -> None:
        """Warm start from a plan: its memberships, routes and (scaled) times."""
        p, model = self.problem, self.model
        model.clear_hints()  # type: ignore[no-untyped-call]
        schedule = self.canonical(schedule)
        times = earliest(
            p,
            schedule.coalitions,
            schedule.sequences,
            lambda i, k: self._up(p.travel_from_start(i, k)),
            lambda i, j, k: self._up(p.travel_between(i, j, k)),
            lambda k, members: max(self._up(p.work[i][k]) for i in members),
            0,
        )
        if times is None:
            return
        start, end = times
        for (i, k), x in self.x.items():
            model.add_hint(x, i in schedule.coalitions[k])
        used: set[tuple[int, int, int]] = set()
        latest = 0
        for i, sequence in enumerate(schedule.sequences):
            if i in self.idle:
                model.add_hint(self.idle[i], not sequence)
            route = [0, *(k + 1 for k in sequence), 0] if sequence else []
            used.update((i, a, b) for a, b in itertools.pairwise(route))
            arrival = (
                end[sequence[-1]] + self._up(p.travel_to_end(i, sequence[-1]))
                if sequence
                else self._up(p.idle_arrival(i))
            )
            model.add_hint(self.arrival[i], arrival)
            latest = max(latest, arrival)
        for key, arc in self.arcs.items():
            model.add_hint(arc, key in used)
        for k in range(p.n_tasks):
            model.add_hint(self.start[k], start[k])
            model.add_hint(self.end[k], end[k])
        model.add_hint(self.makespan, latest)

    def solve(
        self,
        time_limit: float,
        seed: int,
        *,
        hint: Schedule | None = None,
        workers: int = 2,
    ) -> Outcome:
        """Minimise the makespan, then the cost (see the module's docstring)."""
        p = self.problem
        if hint is not None:
            self.hint(hint)
        self.model.minimize(self.makespan)
        solver = make_solver(time_limit, seed, workers)
        status = solver.solve(self.model)
        if status == cp_model.INFEASIBLE:
            return Outcome(None, 0.0, False, True)
        if status not in (cp_model.OPTIMAL, cp_model.FEASIBLE):
            return Outcome(hint, 0.0, False, False)
        optimal = status == cp_model.OPTIMAL
        bound = max(0.0, solver.best_objective_bound / self.scale - self.slack)
        found = self.read(solver)
        if hint is not None and hint.makespan < found.makespan:
            found = hint
        remaining = time_limit - solver.wall_time
        if self.has_cost and remaining > 0.05:
            found, cheapest = self._cheapest(
                found, solver.value(self.makespan), remaining, seed, workers
            )
            # For cost and balanced, "optimal" is about the cost (under their bound).
            optimal = cheapest if p.priority != "time" else optimal
        return Outcome(found, min(bound, found.makespan), optimal, False)

    def _cheapest(
        self, fastest: Schedule, makespan: int, time_limit: float, seed: int, workers: int
    ) -> tuple[Schedule, bool]:
        """The cheapest plan within the priority's makespan bound; proven cheapest?"""
        p = self.problem
        if p.priority == "time":
            limit = makespan
        elif p.priority == "balanced":
            limit = math.floor(makespan * BALANCED_SLACK)
        else:
            limit = self.horizon
        self.hint(fastest)
        self.model.add(self.makespan <= limit)
        self.model.minimize(self.cost)
        solver = make_solver(time_limit, seed, workers)
        status = solver.solve(self.model)
        if status not in (cp_model.OPTIMAL, cp_model.FEASIBLE):
            return fastest, False
        cheaper = self.read(solver)
        proven = status == cp_model.OPTIMAL
        return (cheaper, proven) if cheaper.cost <= fastest.cost else (fastest, proven)

    def read(self, solver: cp_model.CpSolver) -> Schedule:
        p = self.problem
        coalitions = [
            tuple(sorted(
                [i for i in range(p.n_robots) if (i, k) in self.x and solver.boolean_value(
                    self.x[i, k])] + self.fixed_members[k]
            ))
            for k in range(p.n_tasks)
        ]
        following: dict[tuple[int, int], int] = {
            (i, a): b for (i, a, b), arc in self.arcs.items() if solver.boolean_value(arc)
        }
        sequences = []
        for i in range(p.n_robots):
            if i in self.fixed:
                sequences.append(tuple(self.fixed[i]))
                continue
            route: list[int] = []
            node = following.get((i, 0), 0)
            while node != 0:
                route.append(node - 1)
                node = following[i, node]
            sequences.append(tuple(route))
        schedule = timed(p, coalitions, sequences)
        assert schedule is not None  # the model's own order has no cycle
        return pruned(p, schedule)


def _twins(problem: Problem) -> list[list[int]]:
    """Groups of robots alike in everything the model reads (groups of one left out)."""
    groups: dict[tuple[object, ...], list[int]] = {}
    p = problem
    for i in range(p.n_robots):
        key = (
            p.brings[i], p.start_distance[i], p.speed[i], p.work[i], p.use_cost[i],
            p.travel_cost_per_m[i],
            None if p.start_end_distance is None else p.start_end_distance[i],
        )
        groups.setdefault(key, []).append(i)
    return [g for g in groups.values() if len(g) > 1]


def make_solver(time_limit: float, seed: int, workers: int) -> cp_model.CpSolver:
    solver = cp_model.CpSolver()
    parameters = solver.parameters
    parameters.max_time_in_seconds = max(0.01, time_limit)
    parameters.num_workers = workers
    parameters.random_seed = seed
    # The same seed, the same answer: the workers take turns deterministically.
    # One chunk of work per batch: with larger batches the turns waited on each
    # other and the 8-task instances took seconds instead of a tenth.
    parameters.interleave_search = workers > 1
    parameters.interleave_batch_size = 1
    return solver


def trivial_horizon(problem: Problem) -> float:
    """A makespan no optimal plan exceeds: every task alone, one after another."""
    total = 0.0
    for k in range(problem.n_tasks):
        total += max(w for row in problem.work for w in [row[k]] if math.isfinite(w))
    longest = max(
        (max(row) for row in problem.task_distance), default=0.0
    ) + max((max(row) for row in problem.start_distance), default=0.0)
    slowest = min(problem.speed)
    end = max(problem.end_distance or [0.0]) + max(problem.start_end_distance or [0.0])
    return total + (problem.n_tasks + 1) * longest / slowest + end / slowest

