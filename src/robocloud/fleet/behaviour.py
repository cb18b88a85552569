"""How a robot answers commands and spends its battery.

The rules behind the Ack of ``robocloud.fleet.messages``, shared by the fleet
simulator, the in-memory link and the gateways so all refuse the same
commands with the same sentences, and report a finished task alike. A real
robot may use its own battery model; the reasons it refuses should be these.

Battery model (choice): driving costs ``DRAIN_PER_M`` percent per metre and
working ``DRAIN_PER_S`` percent per second, whatever the capability.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from robocloud.domain import Capability
from robocloud.fleet.messages import Assign, TaskProgress

DRAIN_PER_M = 0.01  # percent of battery per metre driven
DRAIN_PER_S = 0.02  # percent of battery per second of work
# Seconds a finished task stays a robot's ``task`` (docs/protocol.md: "for a
# few seconds"); after that only its ``last_task`` says it.
FINISHED_LINGER = 3.0


def distance(a: Sequence[float], b: Sequence[float]) -> float:
    return math.hypot(b[0] - a[0], b[1] - a[1])


def energy_needed(metres: float, work_seconds: float) -> float:
    """Percent of battery a task of ``metres`` of driving and ``work_seconds`` of work takes."""
    return metres * DRAIN_PER_M + work_seconds * DRAIN_PER_S


def refuse_assign(
    robot_id: str,
    status: str,
    current_request: str | None,
    capabilities: Mapping[str, Capability],
    battery: float,
    position: Sequence[float],
    command: Assign,
) -> str | None:
    """Why the robot refuses ``command``, or None when it takes it.

    ``current_request`` is the request the robot is working on, if any; an
    assign repeated for that request is taken again (None).
    """
    if current_request == command.request_id:
        return None
    if current_request is not None:
        return f"robot {robot_id} is busy with request {current_request}."
    if status != "idle":
        return f"robot {robot_id} is {status}, not idle."
    missing = [name for name in command.capabilities if name not in capabilities]
    if missing:
        noun = "capability" if len(missing) == 1 else "capabilities"
        return f"robot {robot_id} lacks the {noun} {', '.join(missing)}."
    need = energy_needed(distance(position, command.location), command.work_time(capabilities))
    # Strictly more: a robot arriving with an empty battery could not report done.
    if battery <= need:
        return (
            f"robot {robot_id}'s battery ({battery:.1f}%) is too low for this task, "
            f"which needs {need:.1f}%."
        )
    return None


def refuse_cancel(robot_id: str, current_request: str | None, request_id: str) -> str | None:
    """Why the robot refuses to cancel ``request_id``, or None when the cancel is ok.

    A robot with no task has nothing to stop: ok, so a repeated cancel is
    harmless. A robot on another request says so.
    """
    if current_request is None or current_request == request_id:
        return None
    return f"robot {robot_id} is not on request {request_id} but on request {current_request}."


def task_to_report(
    current: TaskProgress | None, finished: TaskProgress | None, finished_until: float, now: float
) -> TaskProgress | None:
    """The ``task`` a robot's state says: the one under way, else the one it
    finished while that lingers (until ``finished_until``), else none."""
    if current is None and finished is not None and now < finished_until:
        return finished
    return current
