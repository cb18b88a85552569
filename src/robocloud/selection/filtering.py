"""Filtering (thesis Algorithm 2, Filter_Robots).

The thesis keeps the idle robots whose battery is at least the filtering rule.
MODEL.md adds that a robot bringing none of the required capabilities is
dropped too: it could only add cost, so no Pareto point changes.
"""

from __future__ import annotations

from collections.abc import Sequence

from robocloud.domain import Robot, Task


def filter_robots(robots: Sequence[Robot], task: Task) -> list[Robot]:
    """The candidates, in the order given: idle, charged to ``task.min_battery``,
    and bringing a required capability."""
    required = frozenset(task.required)  # a property that builds a dict: once, not per robot
    return [
        robot
        for robot in robots
        if robot.status == "idle"
        and robot.battery >= task.min_battery
        and not required.isdisjoint(robot.capabilities)
    ]
