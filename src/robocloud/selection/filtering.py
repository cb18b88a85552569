"""Filtering (thesis Algorithm 2, Filter_Robots).

The thesis keeps the idle robots whose battery is at least the filtering rule.
docs/model.md adds that a robot bringing none of the required capabilities is
dropped too: it could only add cost, so no Pareto point changes.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeVar

from robocloud.domain import RobotLike, Task

R = TypeVar("R", bound=RobotLike)


def filter_robots(robots: Sequence[R], task: Task) -> list[R]:
    """The candidates, in the order given: idle, charged to ``task.min_battery``,
    and bringing a required capability.

    Robot by robot, so filtering a fleet piece by piece and joining the pieces
    gives the same list (``robocloud select`` filters a large file that way).
    """
    required = frozenset(task.required)  # a property that builds a dict: once, not per robot
    return [
        robot
        for robot in robots
        if robot.status == "idle"
        and robot.battery >= task.min_battery
        and not required.isdisjoint(robot.capabilities)
    ]
