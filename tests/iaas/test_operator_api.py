"""What an operator reads in the API (issue 26): where each priority would choose,
unknown capabilities refused at once, batteries rounded for display."""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import pytest
from fastapi.testclient import TestClient

from robocloud.domain import Robot
from robocloud.federation.capabilities import Announced
from robocloud.fleet import MemoryRobotLink
from robocloud.iaas.app import create_app
from robocloud.iaas.config import Settings
from robocloud.storage import MemoryRequestStore

A = {"Authorization": "Bearer key-a"}
# MODEL.md's worked example of the choice: (T, C) of three one-robot coalitions.
WORKED = {"a-0001": (300.0, 210.0), "a-0002": (600.0, 150.0), "a-0003": (1200.0, 120.0)}


def robot(rid: str, time_s: float, cost: float, battery: float = 90.0) -> Robot:
    return Robot.model_validate(
        {
            "id": rid,
            "cloud": "cloud-a",
            "position": [0.0, 0.0],  # at the task's location: t_i and c_i are the capability's
            "speed": 1.0,
            "battery": battery,
            "status": "idle",
            "travel_cost_per_m": 0.1,
            "capabilities": {"hose": {"kind": "actuating", "time": time_s, "cost": cost}},
        }
    )


def task(priority: str, **changes: Any) -> dict[str, Any]:
    return {
        "location": [0.0, 0.0],
        "actuating": {"hose": 1},
        "max_robots": 1,
        "max_cost": 1000.0,
        "max_time": 2000.0,
        "priority": priority,
        **changes,
    }


@pytest.fixture
def client() -> Iterator[TestClient]:
    robots = [robot(rid, t, c) for rid, (t, c) in WORKED.items()]
    robots.append(robot("a-0004", 50.0, 5.0, battery=86.12345678901234))
    robots[-1] = robots[-1].model_copy(update={"status": "offline"})
    settings = Settings(
        cloud="cloud-a", api_keys={"key-a": "app-a"}, selection_workers=0, offline_after=60.0
    )
    app = create_app(settings, store=MemoryRequestStore(), link=MemoryRobotLink("cloud-a", robots))
    with TestClient(app) as c:
        yield c


def decided(client: TestClient, rid: str) -> dict[str, Any]:
    deadline = time.monotonic() + 10
    while True:
        body: dict[str, Any] = client.get(f"/v1/requests/{rid}", headers=A).json()
        if body["state"] not in ("received", "selecting"):
            return body
        assert time.monotonic() < deadline, body
        time.sleep(0.02)


@pytest.mark.parametrize(("priority", "robot_id"),
                         [("balanced", "a-0002"), ("time", "a-0001"), ("cost", "a-0003")])
def test_choices_say_where_each_priority_would_choose(
    client: TestClient, priority: str, robot_id: str
) -> None:
    answer = client.post("/v1/requests", json=task(priority), headers=A)
    assert answer.status_code == 202
    body = decided(client, answer.json()["id"])
    front = body["pareto"]
    assert [m["robots"] for m in front] == [["a-0001"], ["a-0002"], ["a-0003"]]
    # The same for every priority: the front is the same; only the choice moves.
    assert body["choices"] == {"balanced": 1, "time": 0, "cost": 2}
    assert front[body["choices"][priority]] == body["chosen"]
    assert body["chosen"]["robots"] == [robot_id]


def test_no_front_means_no_choices(client: TestClient) -> None:
    rid = client.post("/v1/requests", json=task("time", max_time=10.0), headers=A).json()["id"]
    body = decided(client, rid)
    assert body["state"] == "rejected" and body["pareto"] == []
    assert body["choices"] is None


def test_a_capability_no_robot_announced_is_refused_at_once(client: TestClient) -> None:
    answer = client.post(
        "/v1/requests", json=task("balanced", sensing={"thermal": 1}), headers=A
    )
    assert answer.status_code == 422
    detail = answer.json()["detail"]
    assert detail.startswith("sensing.thermal: no robot of this cloud has announced the "
                             "capability 'thermal'")
    assert "hose" in detail  # what there is
    assert client.get("/v1/requests", headers=A).json()["items"] == []  # nothing stored


def test_a_capability_heard_later_is_accepted(client: TestClient) -> None:
    link: MemoryRobotLink = client.app.state.service.link  # type: ignore[attr-defined]
    assert client.post("/v1/requests", json=task("time", actuating={"foam": 1}),
                       headers=A).status_code == 422
    foam = robot("a-0009", 10.0, 1.0).model_copy(
        update={"capabilities": {"foam": robot("x", 10.0, 1.0).capabilities["hose"]}}
    )
    link.put(foam)
    assert client.post("/v1/requests", json=task("time", actuating={"foam": 1}),
                       headers=A).status_code == 202


def test_battery_is_rounded_for_display(client: TestClient) -> None:
    robots = {r["id"]: r for r in client.get("/v1/robots", headers=A).json()}
    assert robots["a-0004"]["battery"] == 86.1
    assert robots["a-0001"]["battery"] == 90.0


def test_the_catalogue_of_names_is_bounded() -> None:
    names = Announced(limit=2)
    names.learn(["b", "a", "c"])
    assert names.names() == ["a", "b"] and names.full
    assert "c" not in names
