"""The coalition problem: each candidate's t_i, c_i and U_i as arrays.

MODEL.md, "Per robot, for one task": d_i is the distance to the task's
location, t_i = d_i / speed_i + exec_i (exec_i the max or the sum of the used
capabilities' times), c_i = travel_cost_per_m_i * d_i + the sum of the used
capabilities' costs, and U_i the required capabilities the robot brings.

Every optimizer works on this one object: it evaluates T(S) = max t_i,
C(S) = sum c_i and N(S) = |S| for many coalitions at once (Algorithm 5,
"Evaluate Population").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from robocloud.domain import Coalition, RobotLike, Task
from robocloud.domain.numeric import margin_array

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class RobotTerms:
    """t_i, c_i and U_i for a list of robots and one task."""

    time: FloatArray  # t_i
    cost: FloatArray  # c_i
    uses: BoolArray  # (n, K): robot i brings required capability k
    capabilities: tuple[str, ...]  # the K required names, sorted


def robot_terms(robots: Sequence[RobotLike], task: Task) -> RobotTerms:
    required = task.required
    names = tuple(required)
    n, k = len(robots), len(names)
    # Columns built from lists, then set in one assignment each: the same
    # float64 values as setting them robot by robot, in half the time.
    position = np.array([robot.position for robot in robots], dtype=np.float64).reshape(n, 2)
    speed = np.array([robot.speed for robot in robots], dtype=np.float64)
    travel = np.array([robot.travel_cost_per_m for robot in robots], dtype=np.float64)
    cap_time = np.zeros((n, k))
    cap_cost = np.zeros((n, k))
    uses = np.zeros((n, k), dtype=bool)
    column = {name: j for j, name in enumerate(names)}
    rows: list[int] = []
    columns: list[int] = []
    times: list[float] = []
    costs: list[float] = []
    for i, robot in enumerate(robots):
        for name, capability in robot.capabilities.items():
            j = column.get(name)
            if j is not None:
                rows.append(i)
                columns.append(j)
                times.append(capability.time)
                costs.append(capability.cost)
    uses[rows, columns] = True
    cap_time[rows, columns] = times
    cap_cost[rows, columns] = costs
    return terms_of(position[:, 0], position[:, 1], speed, travel, cap_time, cap_cost, uses, task)


def terms_of(
    x: FloatArray,
    y: FloatArray,
    speed: FloatArray,
    travel: FloatArray,
    cap_time: FloatArray,
    cap_cost: FloatArray,
    uses: BoolArray,
    task: Task,
) -> RobotTerms:
    """t_i, c_i and U_i from the robots' columns (``cap_*`` and ``uses``: one column per
    required capability, in ``task.required``'s order, zero where a robot lacks it).

    ``robot_terms`` and the columnar fleet (``robocloud.selection.columns``)
    both end here, so their numbers agree bit for bit.
    """
    distance = np.hypot(x - task.location[0], y - task.location[1])
    if task.execution == "parallel":
        execution = cap_time.max(axis=1, initial=0.0)
    else:
        execution = cap_time.sum(axis=1)
    time = distance / speed + execution
    cost = travel * distance + cap_cost.sum(axis=1)
    return RobotTerms(time=time, cost=cost, uses=uses, capabilities=tuple(task.required))


@dataclass(frozen=True)
class CoalitionProblem:
    """The candidates of one task, ready for an optimizer.

    Indices 0..n-1 refer to ``ids``; ``need[k]`` is how many robots must bring
    capability ``capabilities[k]``.
    """

    ids: tuple[str, ...]
    time: FloatArray
    cost: FloatArray
    uses: BoolArray
    capabilities: tuple[str, ...]
    need: IntArray
    max_robots: int
    max_cost: float
    max_time: float

    @classmethod
    def build(cls, candidates: Sequence[RobotLike], task: Task) -> CoalitionProblem:
        ids = tuple(robot.id for robot in candidates)
        return cls.of_terms(ids, robot_terms(candidates, task), task)

    @classmethod
    def of_terms(cls, ids: tuple[str, ...], terms: RobotTerms, task: Task) -> CoalitionProblem:
        """The problem of the candidates ``ids``, whose terms are ``terms``."""
        return cls(
            ids=ids,
            time=terms.time,
            cost=terms.cost,
            uses=terms.uses,
            capabilities=terms.capabilities,
            need=np.array(list(task.required.values()), dtype=np.int64),
            max_robots=task.max_robots,
            max_cost=task.max_cost,
            max_time=task.max_time,
        )

    @property
    def size(self) -> int:
        return len(self.ids)

    @property
    def largest_useful_coalition(self) -> int:
        """No Pareto-optimal coalition is larger: a robot whose removal keeps
        every count met only adds time, cost and one to N, so a coalition of
        more than sum(need) robots always holds such a robot."""
        return int(min(self.max_robots, int(self.need.sum())))

    def subproblem(self, indices: Sequence[int] | IntArray) -> CoalitionProblem:
        idx = np.asarray(indices, dtype=np.int64)
        return CoalitionProblem(
            ids=tuple(self.ids[i] for i in idx),
            time=self.time[idx],
            cost=self.cost[idx],
            uses=self.uses[idx],
            capabilities=self.capabilities,
            need=self.need,
            max_robots=self.max_robots,
            max_cost=self.max_cost,
            max_time=self.max_time,
        )

    # Algorithm 5, Evaluate Population: the whole swarm at once.
    def evaluate(self, members: BoolArray) -> tuple[FloatArray, FloatArray, IntArray]:
        """T, C and N for each row of a (m, n) membership matrix."""
        members = np.asarray(members, dtype=bool)
        time = np.where(members, self.time, -np.inf).max(axis=1, initial=-np.inf)
        time = np.where(np.isfinite(time), time, 0.0)
        cost = members @ self.cost
        size = members.sum(axis=1).astype(np.int64)
        return time, cost, size

    def covers(self, members: BoolArray) -> BoolArray:
        """Rows whose robots bring every required capability often enough."""
        counts = np.asarray(members, dtype=np.int64) @ self.uses.astype(np.int64)
        return np.asarray((counts >= self.need).all(axis=1))

    def feasible(self, members: BoolArray) -> BoolArray:
        """MODEL.md's feasibility, with the thresholds compared under the tolerance."""
        time, cost, size = self.evaluate(members)
        tol_t = margin_array(time)
        tol_c = margin_array(cost)
        return np.asarray(
            self.covers(members)
            & (size <= self.max_robots)
            & (cost <= self.max_cost + tol_c)
            & (time <= self.max_time + tol_t)
        )

    def coalition(self, indices: Sequence[int] | IntArray) -> Coalition:
        # Summed in index order, so the same set always has the same float cost.
        idx = sorted(int(i) for i in indices)
        return Coalition(
            robots=tuple(sorted(self.ids[i] for i in idx)),
            time=float(self.time[idx].max()) if idx else 0.0,
            cost=float(self.cost[idx].sum()) if idx else 0.0,
        )
