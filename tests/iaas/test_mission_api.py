"""The /v1/missions routes over the in-memory store and robot link (MISSION_API.md)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
from fastapi.testclient import TestClient

from robocloud.domain import Robot
from robocloud.fleet import MemoryRobotLink
from robocloud.iaas.app import create_app
from robocloud.iaas.config import Settings
from robocloud.storage import MemoryRequestStore

A = {"Authorization": "Bearer key-a"}
B = {"Authorization": "Bearer key-b"}
# No robot brings "hose": the mission is refused at once, without a planner process.
NOBODY: dict[str, Any] = {
    "label": "two fires",
    "tasks": [
        {"id": "f1", "location": [0, 10], "actuating": {"hose": 1}},
        {"id": "f2", "location": [5, 10], "actuating": {"hose": 1}},
    ],
    "precedence": [["f1", "f2"]],
    "time_limit": 0.5,
}


@pytest.fixture
def client() -> Iterator[TestClient]:
    robot = Robot.model_validate({
        "id": "a-0001", "cloud": "cloud-a", "position": [0.0, 0.0], "speed": 1.0,
        "battery": 90.0, "status": "idle", "travel_cost_per_m": 0.1,
        "capabilities": {"grabber": {"kind": "actuating", "time": 5.0, "cost": 1.0}},
    })
    settings = Settings(
        cloud="cloud-a", api_keys={"key-a": "app-a", "key-b": "app-b"}, selection_workers=0
    )
    app = create_app(settings, store=MemoryRequestStore(), link=MemoryRobotLink("cloud-a", [robot]))
    with TestClient(app) as c:
        yield c


def test_a_mission_is_posted_read_listed_and_followed(client: TestClient) -> None:
    posted = client.post("/v1/missions", json=NOBODY, headers={**A, "Idempotency-Key": "k1"})
    assert posted.status_code == 202, posted.text
    mission = posted.json()
    assert posted.headers["Location"] == f"/v1/missions/{mission['id']}"
    assert mission["label"] == "two fires" and mission["state"] == "planning"
    again = client.post("/v1/missions", json=NOBODY, headers={**A, "Idempotency-Key": "k1"})
    assert again.json()["id"] == mission["id"]
    other = client.post(
        "/v1/missions", json={**NOBODY, "label": "x"}, headers={**A, "Idempotency-Key": "k1"}
    )
    assert other.status_code == 422 and "Idempotency-Key" in other.json()["detail"]
    with client.stream("GET", f"/v1/missions/{mission['id']}/events", headers=A) as events:
        lines = [line for line in events.iter_lines() if line.startswith("data:")]
    assert '"state":"rejected"' in lines[-1].replace(" ", "")  # the stream ends when final
    shown = client.get(f"/v1/missions/{mission['id']}", headers=A).json()
    assert shown["state"] == "rejected" and "hose" in shown["reason"]
    listed = client.get("/v1/missions", params={"state": "rejected"}, headers=A).json()
    assert [m["id"] for m in listed["missions"]] == [mission["id"]] and listed["next"] is None
    assert client.get(f"/v1/missions/{mission['id']}", headers=B).status_code == 404
    assert client.get("/v1/missions", headers=B).json()["missions"] == []
    assert client.delete(f"/v1/missions/{mission['id']}", headers=A).json()["state"] == "rejected"


def test_bad_missions_and_unknown_ones_get_a_sentence(client: TestClient) -> None:
    cycle = {**NOBODY, "precedence": [["f1", "f2"], ["f2", "f1"]]}
    answer = client.post("/v1/missions", json=cycle, headers=A)
    assert answer.status_code == 422 and "cycle" in answer.json()["detail"]
    answer = client.post("/v1/missions", json={**NOBODY, "time_limit": 0.1}, headers=A)
    assert answer.status_code == 422 and "time_limit" in answer.json()["detail"]
    assert client.post("/v1/missions", json=[1], headers=A).status_code == 422
    for path in ("/v1/missions/mis-aaaaaaaaaaaa", "/v1/missions/0/events"):
        answer = client.get(path, headers=A)
        assert answer.status_code == 404 and "no mission" in answer.json()["detail"]
    assert client.delete("/v1/missions/nope", headers=A).status_code == 404
    assert client.post("/v1/missions", json=NOBODY).status_code == 401
