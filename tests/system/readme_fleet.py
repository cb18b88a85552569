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


def leave(cloud: Cloud, robots: list[ReadmeRobot], timeout: float = 10) -> None:
    """Close ``robots`` and wait until the IaaS lists each offline (past ``--offline-after``).

    For a cloud shared by a file's tests: a robot just closed still looks idle
    until then, and the next test's request could choose it.
    """
    for robot in robots:
        robot.close()
    gone = {robot.id for robot in robots}
    with cloud.client() as client:
        wait_until(
            lambda: all(
                r["status"] == "offline" for r in client.get("/v1/robots").json() if r["id"] in gone
            ),
            timeout,
            f"{', '.join(sorted(gone))} to be listed offline",
        )


def details(request: dict[str, Any]) -> list[str]:
    return [h["detail"] or "" for h in request["history"]]
