"""A fleet as columns: Filter_Robots (thesis Algorithm 2) and the robots' terms over arrays.

An IaaS follows tens of thousands of robots and a selection keeps a few
thousand of them. Visiting 50,000 ``Robot`` objects in Python, then making the
candidates into tuples and pickling them to the selection's worker, took
longer than the selection itself. The robot link
(``robocloud.fleet.columns.StateColumns``) keeps each robot as one row of
arrays instead, written when a state changes what the robot says, and a
selection reads a snapshot of them (``FleetColumns``):

- ``filter_rows`` is ``filter_robots`` as one vectorised mask (idle, battery
  at least ``min_battery``, bringing a required capability), less the robots
  reserved or held meanwhile;
- ``candidate_problem`` builds the candidates' t_i, c_i and U_i from their
  rows with ``robocloud.selection.problem.terms_of``, the function
  ``robot_terms`` ends in, so the numbers are the same bit for bit;
- the worker receives that ``CoalitionProblem`` (a few arrays and the ids)
  and runs the pipeline from the ranking on (``select_problem``).

Capability sets are few (robots of a kind share one): each distinct set is
stored once in ``CapabilitySets`` and a robot's row holds its index. What a
set brings to a task (U, times and costs of the required capabilities) is
worked out once per set and per list of required names.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from robocloud.domain import Capability, RobotLike, Task
from robocloud.domain.robot import ROBOT_STATUSES
from robocloud.selection.filtering import filter_robots
from robocloud.selection.problem import (
    BoolArray,
    CoalitionProblem,
    FloatArray,
    IntArray,
    RobotTerms,
    robot_terms,
    terms_of,
)

# A robot's status as a small integer, in ROBOT_STATUSES's order.
STATUS_CODES: dict[str, int] = {status: code for code, status in enumerate(ROBOT_STATUSES)}
IDLE = STATUS_CODES["idle"]
OFFLINE = STATUS_CODES["offline"]

ObjectArray = npt.NDArray[np.object_]
SetTable = tuple[BoolArray, FloatArray, FloatArray]  # uses, times, costs: (sets, K) each

_MAX_TABLES = 64  # lists of required names whose tables are kept
_MAX_SEEN = 100_000  # capability mappings recognised by identity


class CapabilitySets:
    """The distinct capability sets of a fleet, each with an index (append-only).

    ``index`` is called by one writer at a time (the link, under its lock);
    ``table`` from any thread, for the sets a snapshot counts.
    """

    def __init__(self) -> None:
        self._sets: list[Mapping[str, Capability]] = []
        self._index: dict[tuple[tuple[str, str, float, float], ...], int] = {}
        # The mapping objects seen, by identity: states of a kind share one
        # (``robocloud.fleet.ingest.StateReader``), so most lookups stop here.
        self._seen: dict[int, tuple[Mapping[str, Capability], int]] = {}
        self._tables: dict[tuple[str, ...], SetTable] = {}
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._sets)

    def index(self, capabilities: Mapping[str, Capability]) -> int:
        seen = self._seen.get(id(capabilities))
        if seen is not None and seen[0] is capabilities:
            return seen[1]
        key = tuple((name, c.kind, c.time, c.cost) for name, c in capabilities.items())
        found = self._index.get(key)
        if found is None:
            found = self._index[key] = len(self._sets)
            self._sets.append(capabilities)
        if len(self._seen) >= _MAX_SEEN:
            self._seen.clear()
        self._seen[id(capabilities)] = (capabilities, found)
        return found

    def table(self, names: tuple[str, ...], count: int) -> SetTable:
        """For sets 0..count-1: which of ``names`` each brings, with those capabilities'
        times and costs (zero where it lacks one), as ``robot_terms`` fills them."""
        with self._lock:
            known = self._tables.get(names)
            have = 0 if known is None else known[0].shape[0]
            if known is None or have < count:
                column = {name: j for j, name in enumerate(names)}
                uses = np.zeros((count - have, len(names)), dtype=bool)
                time = np.zeros((count - have, len(names)))
                cost = np.zeros((count - have, len(names)))
                for i in range(have, count):
                    for name, capability in self._sets[i].items():
                        j = column.get(name)
                        if j is not None:
                            uses[i - have, j] = True
                            time[i - have, j] = capability.time
                            cost[i - have, j] = capability.cost
                if known is not None:
                    uses = np.concatenate([known[0], uses])
                    time = np.concatenate([known[1], time])
                    cost = np.concatenate([known[2], cost])
                if names not in self._tables and len(self._tables) >= _MAX_TABLES:
                    self._tables.clear()
                known = self._tables[names] = (uses, time, cost)
        return known[0][:count], known[1][:count], known[2][:count]


@dataclass(frozen=True)
class FleetColumns:
    """A fleet at one moment, one row per robot, in id order (as ``RobotLink.robots()``).

    ``status`` already says offline for a robot silent too long.
    """

    ids: list[str]  # sorted
    id_array: ObjectArray  # the same, for gathering rows
    row_of: Mapping[str, int]  # each id's row
    cloud: ObjectArray
    status: npt.NDArray[np.int8]  # STATUS_CODES
    battery: FloatArray
    x: FloatArray
    y: FloatArray
    speed: FloatArray
    travel: FloatArray  # travel_cost_per_m
    capability_set: IntArray  # index in ``sets``
    sets: CapabilitySets
    set_count: int

    def __len__(self) -> int:
        return len(self.ids)

    def rows_of(self, ids: Iterable[str]) -> IntArray:
        """The rows of those of ``ids`` that are in the fleet.

        A selection leaves out every robot reserved, hundreds under load: a
        dictionary beats a binary search of each in ``ids``
        (benchmarks/results/design-notes.md, row-of).
        """
        row_of = self.row_of
        return np.array([row_of[r] for r in ids if r in row_of], dtype=np.int64)

    def table(self, task: Task) -> SetTable:
        return self.sets.table(tuple(task.required), self.set_count)


def filter_rows(columns: FleetColumns, task: Task, excluded: Iterable[str] = ()) -> IntArray:
    """Filter_Robots (Algorithm 2) over columns: the rows ``filter_robots`` keeps, in id order.

    A robot in ``excluded`` (reserved or held by another request, or to be
    left out of this selection) counts as not idle.
    """
    uses, _, _ = columns.table(task)
    brings = np.asarray(uses.any(axis=1))[columns.capability_set]
    keep = (columns.status == IDLE) & (columns.battery >= task.min_battery) & brings
    keep[columns.rows_of(excluded)] = False
    return np.flatnonzero(keep)


def rows_terms(columns: FleetColumns, rows: IntArray, task: Task) -> RobotTerms:
    """``robot_terms`` of the robots in ``rows``."""
    uses, time, cost = columns.table(task)
    sets = columns.capability_set[rows]
    return terms_of(
        columns.x[rows],
        columns.y[rows],
        columns.speed[rows],
        columns.travel[rows],
        time[sets],
        cost[sets],
        uses[sets],
        task,
    )


@dataclass(frozen=True)
class Candidates:
    """The candidates of one selection: the problem the worker solves, and each one's cloud."""

    problem: CoalitionProblem
    clouds: tuple[str, ...]  # in ``problem.ids``'s order


def candidates(
    columns: FleetColumns,
    task: Task,
    excluded: Iterable[str] = (),
    others: Sequence[RobotLike] = (),
) -> Candidates:
    """The filtered candidates among ``columns`` (less ``excluded``), then among ``others``.

    ``others`` (robots of other clouds, as their homes sent them) are few. The
    problem equals ``CoalitionProblem.build(filter_robots(robots, task), task)``
    where ``robots`` lists the fleet in id order, its excluded robots as not
    idle, then ``others``.
    """
    rows = filter_rows(columns, task, excluded)
    terms = rows_terms(columns, rows, task)
    ids = tuple(columns.id_array[rows].tolist())
    clouds = tuple(columns.cloud[rows].tolist())
    if others:
        kept = filter_robots(others, task)
        more = robot_terms(kept, task)
        terms = RobotTerms(
            time=np.concatenate([terms.time, more.time]),
            cost=np.concatenate([terms.cost, more.cost]),
            uses=np.concatenate([terms.uses, more.uses]),
            capabilities=terms.capabilities,
        )
        ids += tuple(robot.id for robot in kept)
        clouds += tuple(robot.cloud for robot in kept)
    return Candidates(CoalitionProblem.of_terms(ids, terms, task), clouds)
