"""``GET /v1/robots`` tells a request's id and progress only to the application that owns it.

Issue 25: another application's request ids and progress showed in every
listing. Over the HTTP API with the in-memory store and robot link: app-a
sends a request; app-b sees the robot working, not for whom nor how far.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from fastapi.testclient import TestClient

from robocloud.domain import Robot
from robocloud.fleet import MemoryRobotLink
from robocloud.iaas.app import create_app
from robocloud.iaas.config import Settings
from robocloud.iaas.robot_list import RobotFilter, remote_rows
from robocloud.storage import MemoryRequestStore

A = {"Authorization": "Bearer key-a"}
B = {"Authorization": "Bearer key-b"}
TASK: dict[str, Any] = {
    "location": [0.0, 0.0],
    "actuating": {"grabber": 1},
    "max_robots": 1,
    "max_cost": 1000.0,
    "max_time": 100000.0,
}


def robot(i: int) -> Robot:
    return Robot.model_validate(
        {
            "id": f"a-{i:04d}",
            "cloud": "cloud-a",
            "position": [100.0, 0.0],
            "speed": 1.0,
            "battery": 90.0,
            "status": "idle",
            "travel_cost_per_m": 0.1,
            "capabilities": {"grabber": {"kind": "actuating", "time": 50.0, "cost": 1.0}},
        }
    )


@pytest.fixture
def fleet() -> MemoryRobotLink:
    return MemoryRobotLink("cloud-a", [robot(0)], offline_after=3600.0)


@pytest.fixture
def client(fleet: MemoryRobotLink) -> Iterator[TestClient]:
    settings = Settings(
        cloud="cloud-a",
        api_keys={"key-a": "app-a", "key-b": "app-b"},
        selection_workers=0,
    )
    with TestClient(create_app(settings, store=MemoryRequestStore(), link=fleet)) as c:
        yield c


def listed(client: TestClient, headers: dict[str, str]) -> dict[str, Any]:
    robots: list[dict[str, Any]] = client.get("/v1/robots", headers=headers).json()
    return {r["id"]: r for r in robots}


def until(check: Callable[[], bool], step: Callable[[], None] = lambda: None) -> None:
    deadline = time.monotonic() + 10
    while not check():
        assert time.monotonic() < deadline, "the condition did not come true in 10 s"
        step()
        time.sleep(0.02)


def test_only_the_owner_sees_a_robots_request_and_progress(
    client: TestClient, fleet: MemoryRobotLink
) -> None:
    rid = client.post("/v1/requests", json=TASK, headers=A).json()["id"]
    # The robot travels 100 m at 1 m/s: a step of 10 s leaves it on its way.
    until(lambda: listed(client, A)["a-0000"]["progress"] is not None, lambda: fleet.step(10))
    mine = listed(client, A)["a-0000"]
    assert mine["request"] == rid and mine["status"] == "busy"
    assert mine["progress"]["phase"] != "done" and mine["progress"]["progress"] < 1.0
    theirs = listed(client, B)["a-0000"]
    assert theirs["status"] == "busy"
    assert theirs["request"] is None and theirs["progress"] is None
    # The same listing for both but for these two (the cache serves each its own).
    assert {k: v for k, v in theirs.items() if k not in ("request", "progress", "seen_ago")} == {
        k: v for k, v in mine.items() if k not in ("request", "progress", "seen_ago")
    }
    assert listed(client, A)["a-0000"]["request"] == rid
    assert rid.encode() not in client.get("/v1/robots", headers=B).content


def test_other_clouds_robots_show_only_the_askers_requests() -> None:
    def remote(request: str | None) -> dict[str, Any]:
        return {
            "id": "b-1", "cloud": "cloud-b", "position": [1, 2], "speed": 1, "battery": 50,
            "status": "busy", "kind": None, "request": request,
            "progress": {"phase": "travel", "progress": 0.5},
            "capabilities": {"light": {"kind": "sensing", "time": 1, "cost": 1}},
        }

    def owns(request: str) -> bool:
        return request == "req-aaaaaaaaaaaa"

    rows = remote_rows([[remote("req-aaaaaaaaaaaa")]], RobotFilter(), "cloud-a", owns)
    assert rows[0][1]["request"] == "req-aaaaaaaaaaaa"
    assert rows[0][1]["progress"] == {"phase": "travel", "progress": 0.5}
    rows = remote_rows([[remote("req-bbbbbbbbbbbb")], [remote(None)]], RobotFilter(),
                       "cloud-a", owns)
    assert [(r["request"], r["progress"], r["status"]) for _, r in rows] == [
        (None, None, "busy"), (None, None, "busy")
    ]
