"""README robots joined to a test's cloud, and what a request's history says (shared helpers)."""

from __future__ import annotations

from typing import Any

from processes import Cloud, wait_until
from readme_robot import ReadmeRobot

GRABBER = {"grabber": {"kind": "actuating", "time": 2.0, "cost": 1.0}}


def join(
    cloud: Cloud,
    robots: list[ReadmeRobot],
    robot_id: str,
    x: float,
    capabilities: dict[str, dict[str, Any]] | None = None,
    **kw: Any,
) -> ReadmeRobot:
    """A README robot of cloud-a at (x, 0), once the IaaS lists it; ``robots`` closes it."""
    robot = ReadmeRobot(
        "cloud-a", robot_id, cloud.zenoh, (x, 0.0), capabilities or GRABBER, **kw
    )
    robots.append(robot)
    with cloud.client() as client:
        wait_until(
            lambda: robot_id in {r["id"] for r in client.get("/v1/robots").json()},
            10,
            f"{robot_id} to be heard",
        )
    return robot


def details(request: dict[str, Any]) -> list[str]:
    return [h["detail"] or "" for h in request["history"]]
