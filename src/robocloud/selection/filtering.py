"""Filtering (thesis Algorithm 2, Filter_Robots).

The thesis keeps the idle robots whose battery is at least the filtering rule.
MODEL.md adds that a robot bringing none of the required capabilities is
dropped too: it could only add cost, so no Pareto point changes.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence

from robocloud.domain import Robot, Task


def is_candidate(robot: Robot, task: Task, required: Collection[str] | None = None) -> bool:
    """Idle, charged to ``task.min_battery``, and bringing a required capability.

    ``required`` is ``task.required``, passed in when many robots are judged
    against one task (it is rebuilt on every access).
    """
    if robot.status != "idle" or robot.battery < task.min_battery:
        return False
    if required is None:
        required = task.required
    return any(name in required for name in robot.capabilities)


def filter_robots(robots: Sequence[Robot], task: Task) -> list[Robot]:
    """The candidates, in the order given."""
    required = frozenset(task.required)
    return [robot for robot in robots if is_candidate(robot, task, required)]
