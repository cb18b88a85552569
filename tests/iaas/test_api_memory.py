"""The HTTP API over the in-memory store and robot link: fast, no network."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
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
SENT = ("dispatched", "underway")  # a robot may report travel before the GET
KINDS = {"light": "sensing", "grabber": "actuating", "kicker": "actuating"}


def robot(i: int, caps: dict[str, tuple[float, float]], x: float = 10.0) -> Robot:
    return Robot.model_validate(
        {
            "id": f"a-{i:04d}",
            "cloud": "cloud-a",
            "position": [x, 0.0],
            "speed": 1.0,
            "battery": 90.0,
            "status": "idle",
            "travel_cost_per_m": 0.1,
            "capabilities": {
                n: {"kind": KINDS[n], "time": t, "cost": c} for n, (t, c) in caps.items()
            },
        }
    )


TASK: dict[str, Any] = {
    "location": [0.0, 0.0],
    "sensing": {"light": 1},
    "actuating": {"grabber": 1},
    "max_robots": 4,
    "max_cost": 100.0,
    "max_time": 300.0,
    "min_battery": 50.0,
    "priority": "time",
}


@pytest.fixture
def fleet() -> MemoryRobotLink:
    robots = [robot(i, {"light": (5, 1), "grabber": (20, 3)}, x=10.0 * (i + 1)) for i in range(6)]
    robots += [robot(10 + i, {"kicker": (5, 1)}) for i in range(2)]
    return MemoryRobotLink("cloud-a", robots)


@pytest.fixture
def client(fleet: MemoryRobotLink) -> Iterator[TestClient]:
    settings = Settings(
        cloud="cloud-a",
        api_keys={"key-a": "app-a", "key-b": "app-b"},
        offline_after=1.0,
        selection_workers=0,  # selections in a thread: no processes to spawn per test
    )
    app = create_app(settings, store=MemoryRequestStore(), link=fleet)
    with TestClient(app) as c:
        yield c


def wait_for(
    client: TestClient,
    rid: str,
    done: Callable[[dict[str, Any]], bool],
    step: Callable[[], None] = lambda: None,
    timeout: float = 10.0,
) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    while True:
        body: dict[str, Any] = client.get(f"/v1/requests/{rid}", headers=A).json()
        if done(body):
            return body
        assert time.monotonic() < deadline, f"timed out in state {body['state']}: {body}"
        step()
        time.sleep(0.02)


def post(client: TestClient, task: dict[str, Any] | None = None, **headers: str) -> Any:
    return client.post("/v1/requests", json=task or TASK, headers={**A, **headers})


def test_request_goes_from_received_to_completed(
    client: TestClient, fleet: MemoryRobotLink
) -> None:
    answer = post(client)
    assert answer.status_code == 202
    rid = answer.json()["id"]
    assert answer.headers["location"] == f"/v1/requests/{rid}"
    body = wait_for(client, rid, lambda b: b["state"] in SENT)
    assert [a["robot"] for a in body["coalition"]] == ["a-0000"]
    assert body["coalition"][0]["capabilities"] == ["grabber", "light"]
    assert body["optimizer"] == "exact" and body["pareto"]
    body = wait_for(client, rid, lambda b: b["state"] == "completed", lambda: fleet.step(5))
    states = [h["state"] for h in body["history"] if h["kind"] == "state"]
    assert states == ["received", "selecting", "dispatched", "underway", "completed"]
    assert body["coalition"][0]["progress"] == {"phase": "done", "progress": 1.0}
    robots = {r["id"]: r for r in client.get("/v1/robots", headers=A).json()}
    assert robots["a-0000"]["status"] == "idle" and robots["a-0000"]["request"] is None
    assert robots["a-0000"]["position"] == [0.0, 0.0]


def test_idempotency_key_returns_the_same_request(client: TestClient) -> None:
    first = post(client, **{"Idempotency-Key": "k-1"}).json()
    again = post(client, **{"Idempotency-Key": "k-1"}).json()
    assert first["id"] == again["id"]
    assert len(client.get("/v1/requests", headers=A).json()["items"]) == 1


def test_applications_see_only_their_own_requests(client: TestClient) -> None:
    rid = post(client).json()["id"]
    assert client.get(f"/v1/requests/{rid}", headers=B).status_code == 404
    assert client.post(f"/v1/requests/{rid}/cancel", headers=B).status_code == 404
    assert client.get("/v1/requests", headers=B).json()["items"] == []


@pytest.mark.parametrize(
    "headers", [{}, {"Authorization": "Bearer nope"}, {"Authorization": "Basic key-a"}]
)
def test_missing_or_wrong_key_is_401(client: TestClient, headers: dict[str, str]) -> None:
    answer = client.get("/v1/requests", headers=headers)
    assert answer.status_code == 401
    assert answer.json()["detail"].endswith(".")


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"max_cost": -1}, "max_cost"),
        ({"priority": "urgent"}, "priority"),
        ({"location": [1.0]}, "location"),
        ({"location": "here"}, "location"),
        ({"actuating": {"grabber": 0}}, "actuating.grabber"),
        ({"max_robots": "many"}, "max_robots"),
        ({"sensing": {}, "actuating": {}}, "at least one"),
        ({"colour": "red"}, "colour"),
    ],
)
def test_bad_task_is_422_naming_the_field(
    client: TestClient, change: dict[str, Any], field: str
) -> None:
    answer = post(client, {**TASK, **change})
    assert answer.status_code == 422
    assert field in answer.json()["detail"]
    assert "Traceback" not in answer.text
    assert client.get("/v1/requests", headers=A).json()["items"] == []


def test_not_json_missing_body_oversized_and_unknown_id(client: TestClient) -> None:
    answer = client.post(
        "/v1/requests", content=b"{not json", headers={**A, "Content-Type": "application/json"}
    )
    assert answer.status_code == 422 and "JSON" in answer.json()["detail"]
    assert client.post("/v1/requests", headers=A).status_code == 422
    big = json.dumps({**TASK, "label": "x" * 100_000})
    answer = client.post(
        "/v1/requests", content=big, headers={**A, "Content-Type": "application/json"}
    )
    assert answer.status_code == 413 and "bytes" in answer.json()["detail"]
    assert client.get("/v1/requests/req-none", headers=A).status_code == 404
    assert client.get("/v1/requests?state=flying", headers=A).status_code == 422


def test_infeasible_task_is_rejected_with_the_reason(client: TestClient) -> None:
    rid = post(client, {**TASK, "actuating": {"grabber": 9}}).json()["id"]
    body = wait_for(client, rid, lambda b: b["state"] == "rejected")
    assert "'grabber' needs 9 robots" in body["reason"]


def test_cancel_stops_the_robots_and_is_idempotent(
    client: TestClient, fleet: MemoryRobotLink
) -> None:
    rid = post(client).json()["id"]
    wait_for(client, rid, lambda b: b["state"] in SENT)
    fleet.step(1)
    first = client.post(f"/v1/requests/{rid}/cancel", headers=A)
    assert first.status_code == 200 and first.json()["state"] == "canceled"
    assert client.post(f"/v1/requests/{rid}/cancel", headers=A).json()["state"] == "canceled"
    # The answer comes once "canceled" is stored; the robots are told right after.
    deadline = time.monotonic() + 5.0
    while fleet.commands[-1][1].type != "cancel":
        assert time.monotonic() < deadline, f"no cancel sent: {fleet.commands}"
        time.sleep(0.01)
    robots = {r["id"]: r for r in client.get("/v1/robots", headers=A).json()}
    assert robots["a-0000"]["request"] is None


def test_cancel_of_a_completed_request_is_409(client: TestClient, fleet: MemoryRobotLink) -> None:
    rid = post(client).json()["id"]
    wait_for(client, rid, lambda b: b["state"] == "completed", lambda: fleet.step(10))
    answer = client.post(f"/v1/requests/{rid}/cancel", headers=A)
    assert answer.status_code == 409 and "completed" in answer.json()["detail"]


def test_a_failed_robot_is_replaced(client: TestClient, fleet: MemoryRobotLink) -> None:
    rid = post(client).json()["id"]
    wait_for(client, rid, lambda b: b["state"] in SENT)
    fleet.step(1)
    fleet.fail("a-0000")
    body = wait_for(
        client, rid, lambda b: any("replaced by" in (h["detail"] or "") for h in b["history"])
    )
    assert [a["robot"] for a in body["coalition"]] == ["a-0001"]
    body = wait_for(client, rid, lambda b: b["state"] == "completed", lambda: fleet.step(10))
    assert any("a-0000 failed" in (h["detail"] or "") for h in body["history"])


def test_a_silent_robot_without_replacement_fails_the_request(
    client: TestClient, fleet: MemoryRobotLink
) -> None:
    rid = post(client, {**TASK, "max_cost": 5.5}).json()["id"]
    wait_for(client, rid, lambda b: b["state"] in SENT)
    fleet.silence("a-0000")

    def heartbeat() -> None:  # every other robot keeps reporting
        for robot_id, state in fleet.states().items():
            if robot_id != "a-0000":
                fleet.put(state)

    body = wait_for(client, rid, lambda b: b["state"] == "failed", heartbeat)
    assert "a-0000 failed" in body["reason"] and "no replacement" in body["reason"]


def test_events_stream_the_current_state_then_changes(
    client: TestClient, fleet: MemoryRobotLink
) -> None:
    rid = post(client).json()["id"]
    wait_for(client, rid, lambda b: b["state"] in SENT)
    client.post(f"/v1/requests/{rid}/cancel", headers=A)
    with client.stream("GET", f"/v1/requests/{rid}/events", headers=A) as stream:
        assert stream.headers["content-type"].startswith("text/event-stream")
        lines = [line for line in stream.iter_lines() if line.startswith("data:")]
    assert json.loads(lines[0][5:])["state"] == "canceled"


def test_openapi_docs_are_served(client: TestClient) -> None:
    assert client.get("/docs").status_code == 200
    paths = client.get("/openapi.json").json()["paths"]
    assert "/v1/requests/{request_id}/cancel" in paths


def test_a_stored_request_that_no_longer_validates_fails_on_restart(
    fleet: MemoryRobotLink,
) -> None:
    store = MemoryRequestStore()
    old, _ = store.create_request("app-a", {**TASK, "colour": "red"}, None, None)
    settings = Settings(cloud="cloud-a", api_keys={"key-a": "app-a"}, selection_workers=0)
    with TestClient(create_app(settings, store=store, link=fleet)) as client:
        body = client.get(f"/v1/requests/{old.id}", headers=A).json()
        assert body["state"] == "failed"
        assert body["reason"].startswith("it could not be resumed after a restart: its stored")
        assert "colour" in body["reason"]
        assert post(client).status_code == 202  # the IaaS serves on
