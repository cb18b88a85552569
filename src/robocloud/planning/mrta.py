"""MRTA-Benchmark instances in, the dataset's solution format out.

The MRTA-Benchmark dataset is by Jakob Bichler (TU Delft, Autonomous
Multi-Robot Lab), DOI 10.4121/10e28ee0-9ad9-450d-8be7-6e6a91f2931f, licensed
CC BY 4.0; its format and rules are stated in ``shared/mrta/README.md``.

An instance is recognised by its fields (``Q``, ``R``, ``T_e``, ``T_t``,
``task_locations``, ``precedence_constraints``). Task ``k`` of the instance
(``1..M``; ``0`` and ``M+1`` are the depots) is task ``k - 1`` of the
:class:`~robocloud.planning.problem.Problem`; skill ``s`` is the capability
named ``str(s)``; every robot has speed 1, so ``T_t`` is both distance and
time, and costs are zero.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from robocloud.errors import InvalidInput
from robocloud.planning.problem import Problem
from robocloud.planning.schedule import Schedule

FIELDS = ("Q", "R", "T_e", "T_t", "task_locations", "precedence_constraints")
# Beyond these sizes an instance is not a benchmark's but a mistake (or an attack).
MAX_TASKS = 1_000
MAX_ROBOTS = 1_000
MAX_SKILLS = 100
MAX_VALUE = 1e9


def is_instance(document: object) -> bool:
    """An MRTA-Benchmark instance has its fields (and a mission has none of them)."""
    return isinstance(document, Mapping) and {"Q", "R", "T_e", "T_t"} <= set(document)


def _number(value: object, field: str, *, least: float = 0.0) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InvalidInput(f"{field} must be a number, not {_shown(value)}.", field)
    number = float(value)
    if not math.isfinite(number) or not least <= number <= MAX_VALUE:
        raise InvalidInput(f"{field} must be between {least:g} and {MAX_VALUE:g}, not {value}.",
                           field)
    return number


def _flag(value: object, field: str) -> bool:
    number = _number(value, field)
    if number not in (0.0, 1.0):
        raise InvalidInput(f"{field} must be 0 or 1, not {value}.", field)
    return number == 1.0


def _list(value: object, field: str, length: int | None = None, *, at_most: int = 0) -> list[Any]:
    if not isinstance(value, list):
        raise InvalidInput(f"{field} must be a list, not {_shown(value)}.", field)
    if length is not None and len(value) != length:
        raise InvalidInput(f"{field} must have {length} entries, not {len(value)}.", field)
    if at_most and len(value) > at_most:
        raise InvalidInput(f"{field} may have at most {at_most} entries, not {len(value)}.", field)
    return value


def _shown(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def read_instance(document: Mapping[str, Any]) -> Problem:
    """The problem of an instance, every field checked (InvalidInput names the first wrong one)."""
    for name in FIELDS:
        if name not in document:
            raise InvalidInput(f"{name} is missing (an MRTA-Benchmark instance has "
                               f"{', '.join(FIELDS)}).", name)
    unknown = sorted(set(document) - set(FIELDS))
    if unknown:
        raise InvalidInput(f"{unknown[0]} is not a field of an MRTA-Benchmark instance.",
                           unknown[0])
    q = _list(document["Q"], "Q", at_most=MAX_ROBOTS)
    if not q:
        raise InvalidInput("Q must list at least one robot.", "Q")
    n_skills = len(_list(q[0], "Q[0]", at_most=MAX_SKILLS))
    if n_skills == 0:
        raise InvalidInput("Q[0] must list at least one skill.", "Q[0]")
    skills = [
        frozenset(
            str(s) for s, has in enumerate(_list(row, f"Q[{i}]", n_skills))
            if _flag(has, f"Q[{i}][{s}]")
        )
        for i, row in enumerate(q)
    ]
    r = _list(document["R"], "R", at_most=MAX_TASKS + 2)
    if len(r) < 2:
        raise InvalidInput("R must have a row for each depot and each task, at least 2.", "R")
    places = len(r)
    m = places - 2
    needs = [
        {str(s): 1 for s, wanted in enumerate(_list(row, f"R[{k}]", n_skills))
         if _flag(wanted, f"R[{k}][{s}]")}
        for k, row in enumerate(r)
    ]
    for k in (0, places - 1):
        if needs[k]:
            raise InvalidInput(f"R[{k}] must be all zero: task {k} is a depot.", f"R[{k}]")
    for k in range(1, places - 1):
        if not needs[k]:
            raise InvalidInput(f"R[{k}] must require at least one skill.", f"R[{k}]")
    durations = [
        _number(d, f"T_e[{k}]")
        for k, d in enumerate(_list(document["T_e"], "T_e", places))
    ]
    travel = [
        [_number(t, f"T_t[{a}][{b}]") for b, t in enumerate(_list(row, f"T_t[{a}]", places))]
        for a, row in enumerate(_list(document["T_t"], "T_t", places))
    ]
    for k, location in enumerate(_list(document["task_locations"], "task_locations", places)):
        for axis, value in enumerate(_list(location, f"task_locations[{k}]", 2)):
            _number(value, f"task_locations[{k}][{axis}]", least=-MAX_VALUE)
    raw_pairs = document["precedence_constraints"]
    pairs: list[tuple[int, int]] = []
    for n, pair in enumerate(_list(raw_pairs, "precedence_constraints") if raw_pairs else []):
        field = f"precedence_constraints[{n}]"
        j, k = _list(pair, field, 2)
        for task in (j, k):
            if isinstance(task, bool) or not isinstance(task, int) or not 1 <= task <= m:
                raise InvalidInput(f"{field} must name two tasks from 1 to {m}, not {pair}.",
                                   field)
        if j == k:
            raise InvalidInput(f"{field} names task {j} twice.", field)
        pairs.append((j - 1, k - 1))
    n = len(skills)
    for s in range(n_skills):
        if not any(str(s) in held for held in skills):
            raise InvalidInput(f"Q: no robot has skill {s}, which every skill needs.", "Q")
    end = places - 1
    problem = Problem(
        robot_ids=tuple(str(i) for i in range(n)),
        task_ids=tuple(str(k) for k in range(1, m + 1)),
        brings=tuple(skills),
        need=tuple(needs[1 : m + 1]),
        task_distance=tuple(tuple(travel[a][1 : m + 1]) for a in range(1, m + 1)),
        start_distance=tuple(tuple(travel[0][1 : m + 1]) for _ in range(n)),
        end_distance=tuple(travel[a][end] for a in range(1, m + 1)),
        start_end_distance=tuple(travel[0][end] for _ in range(n)),
        speed=tuple(1.0 for _ in range(n)),
        work=tuple(
            tuple(durations[k] if skills[i] & needs[k].keys() else math.inf
                  for k in range(1, m + 1))
            for i in range(n)
        ),
        use_cost=tuple(tuple(0.0 for _ in range(m)) for _ in range(n)),
        travel_cost_per_m=tuple(0.0 for _ in range(n)),
        precedence=tuple(pairs),
        priority="time",
    )
    if problem.topological_order() is None:
        raise InvalidInput("precedence_constraints form a cycle: no task of it could start "
                           "first.", "precedence_constraints")
    return problem


def solution(problem: Problem, schedule: Schedule) -> dict[str, Any]:
    """The dataset's schedule format: ``makespan``, ``n_tasks``, ``n_robots`` and
    ``robot_schedules`` (each robot's tasks in order of start)."""
    return {
        "makespan": schedule.makespan,
        "n_tasks": problem.n_tasks,
        "n_robots": problem.n_robots,
        "robot_schedules": {
            str(i): [
                {"task": k + 1, "start_time": schedule.start[k], "end_time": schedule.end[k]}
                for k in sequence
            ]
            for i, sequence in enumerate(schedule.sequences)
        },
    }
