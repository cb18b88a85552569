"""Load shedding: a cloud that cannot keep up refuses new requests (503) instead of
accepting them late.

Over the HTTP API, in process, with selections held back by the test (a
selector that waits for a gate): requests stay ``selecting`` for as long as the
test wants, so the rules are checked exactly. What a refusal must not do:
store anything, or spend an Idempotency-Key.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from fastapi.testclient import TestClient

from robocloud.domain import Robot, Task
from robocloud.fleet import MemoryRobotLink
from robocloud.iaas.admission import BUSY_MIN
from robocloud.iaas.app import create_app
from robocloud.iaas.config import Settings
from robocloud.selection.pipeline import select_problem
from robocloud.selection.problem import CoalitionProblem
from robocloud.selection.result import SelectionResult
from robocloud.storage import MemoryRequestStore

A = {"Authorization": "Bearer key-a"}
TASK: dict[str, Any] = {
    "location": [0.0, 0.0],
    "actuating": {"grabber": 1},
    "max_robots": 1,
    "max_cost": 1000.0,
    "max_time": 100_000.0,
}


def robot(i: int) -> Robot:
    return Robot.model_validate(
        {
            "id": f"a-{i:04d}",
            "cloud": "cloud-a",
            "position": [10.0 + i, 0.0],
            "speed": 1.0,
            "battery": 90.0,
            "status": "idle",
            "travel_cost_per_m": 0.1,
            "capabilities": {"grabber": {"kind": "actuating", "time": 5.0, "cost": 1.0}},
        }
    )


class Held:
    """A selector whose selections wait until the test opens the gate."""

    def __init__(self) -> None:
        self.gate = threading.Event()

    async def __call__(self, problem: CoalitionProblem, task: Task) -> SelectionResult:
        await asyncio.to_thread(self.gate.wait, 30)
        return select_problem(problem, task, "exact", ranking=False)


@pytest.fixture
def cloud() -> Iterator[Callable[..., tuple[TestClient, Held]]]:
    with contextlib.ExitStack() as opened:

        def open_cloud(**settings: Any) -> tuple[TestClient, Held]:
            held = Held()
            app = create_app(
                Settings(cloud="cloud-a", api_keys={"key-a": "app-a"}, **settings),
                store=MemoryRequestStore(),
                link=MemoryRobotLink(
                    "cloud-a", [robot(i) for i in range(20)], offline_after=3600
                ),
                selector=held,
            )
            client = opened.enter_context(TestClient(app))
            # The gate opens before the client closes (last in, first out): a test
            # that failed before opening it leaves no selection waiting out its 30 s.
            opened.callback(held.gate.set)
            return client, held

        yield open_cloud


SENT = {"dispatched", "underway", "completed"}


def settled(client: TestClient, ids: list[str]) -> set[str]:
    deadline = time.monotonic() + 10
    while True:
        states = [client.get(f"/v1/requests/{i}", headers=A).json()["state"] for i in ids]
        if not {"received", "selecting"} & set(states) or time.monotonic() > deadline:
            return set(states)
        time.sleep(0.05)


def refused_count(client: TestClient) -> float:
    for line in client.get("/metrics", headers=A).text.splitlines():
        if line.startswith("robocloud_requests_refused_busy_total "):
            return float(line.split()[1])
    raise AssertionError("no refusal counter in /metrics")


def test_a_cloud_with_max_waiting_requests_refuses_the_next_and_stores_nothing(
    cloud: Callable[..., tuple[TestClient, Held]],
) -> None:
    client, held = cloud(max_waiting=3, busy_after=3600.0)
    ids = [client.post("/v1/requests", json=TASK, headers=A).json()["id"] for _ in range(3)]
    states = [client.get(f"/v1/requests/{i}", headers=A).json()["state"] for i in ids]
    assert set(states) <= {"received", "selecting"}  # their selections are held
    key = {**A, "Idempotency-Key": "fire-17"}
    refused = client.post("/v1/requests", json=TASK, headers=key)
    assert refused.status_code == 503, refused.text
    assert refused.headers["Retry-After"] == "1"
    assert refused.headers["X-Robocloud-Busy"] == "1"  # nothing stored: another cloud may take it
    assert refused.json()["detail"] == (
        "this cloud is busy: 3 requests are waiting for their robots, its limit; "
        "try again after Retry-After seconds."
    )
    assert refused_count(client) == 1
    listed = client.get("/v1/requests", headers=A).json()["items"]
    assert sorted(r["id"] for r in listed) == sorted(ids)  # the refused one left no trace

    held.gate.set()
    assert settled(client, ids) <= SENT
    # Decided, they no longer count: the same request, key and all, is taken now.
    again = client.post("/v1/requests", json=TASK, headers=key)
    assert again.status_code == 202, again.text
    assert client.post("/v1/requests", json=TASK, headers=key).json()["id"] == again.json()["id"]


def test_a_queue_that_waited_too_long_refuses_but_a_few_slow_selections_do_not(
    cloud: Callable[..., tuple[TestClient, Held]],
) -> None:
    client, held = cloud(busy_after=0.2)
    first = client.post("/v1/requests", json=TASK, headers=A)
    time.sleep(0.3)  # the oldest has waited past busy_after from here on
    ids = [first.json()["id"]]
    for _ in range(BUSY_MIN - 1):  # fewer than BUSY_MIN waiting: each is taken
        answer = client.post("/v1/requests", json=TASK, headers=A)
        assert answer.status_code == 202, answer.text
        ids.append(answer.json()["id"])
    refused = client.post("/v1/requests", json=TASK, headers=A)
    assert refused.status_code == 503, refused.text
    detail = refused.json()["detail"]
    assert detail.startswith(f"this cloud is busy: {BUSY_MIN} requests are waiting for their "
                             "robots, the oldest for ")
    assert "(over 0.2 s)" in detail
    assert refused.headers["Retry-After"] == "1"

    held.gate.set()
    assert settled(client, ids) <= SENT
    assert client.post("/v1/requests", json=TASK, headers=A).status_code == 202
    assert refused_count(client) == 1


def test_a_request_without_a_key_is_401_even_when_busy(
    cloud: Callable[..., tuple[TestClient, Held]],
) -> None:
    client, held = cloud(max_waiting=1)
    assert client.post("/v1/requests", json=TASK, headers=A).status_code == 202
    busy = client.post("/v1/requests", json=TASK, headers=A)
    assert busy.status_code == 503
    assert busy.json()["detail"] == (
        "this cloud is busy: 1 request is waiting for its robots, its limit; try again after "
        "Retry-After seconds."
    )
    assert client.post("/v1/requests", json=TASK).status_code == 401
    # Reads and cancels are never shed.
    assert client.get("/v1/requests", headers=A).status_code == 200
    rid = client.get("/v1/requests", headers=A).json()["items"][0]["id"]
    assert client.post(f"/v1/requests/{rid}/cancel", headers=A).json()["state"] == "canceled"
    held.gate.set()
    assert client.post("/v1/requests", json=TASK, headers=A).status_code == 202


def test_a_busy_cloud_answers_a_retry_of_a_request_it_has_with_that_request(
    cloud: Callable[..., tuple[TestClient, Held]],
) -> None:
    client, held = cloud(max_waiting=2, busy_after=3600.0)
    key = {**A, "Idempotency-Key": "fire-18"}
    first = client.post("/v1/requests", json=TASK, headers=key)
    second = client.post("/v1/requests", json=TASK, headers=A)
    assert first.status_code == second.status_code == 202
    # Busy now (2 waiting): the retry of the first (its answer lost, say) gets it ...
    retry = client.post("/v1/requests", json=TASK, headers=key)
    assert retry.status_code == 202, retry.text
    assert retry.json()["id"] == first.json()["id"]
    assert refused_count(client) == 0
    # ... the same key with another body is still told so ...
    other = client.post("/v1/requests", json={**TASK, "max_robots": 2}, headers=key)
    assert other.status_code == 422, other.text
    assert "was already used for another request" in other.json()["detail"]
    # ... and a new key, or none, is refused, counted, and stores nothing.
    new_key = client.post("/v1/requests", json=TASK, headers={**A, "Idempotency-Key": "fire-19"})
    assert new_key.status_code == 503 and new_key.headers["X-Robocloud-Busy"] == "1"
    assert client.post("/v1/requests", json=TASK, headers=A).status_code == 503
    assert refused_count(client) == 2
    listed = client.get("/v1/requests", headers=A).json()["items"]
    assert sorted(r["id"] for r in listed) == sorted([first.json()["id"], second.json()["id"]])
    held.gate.set()
    assert settled(client, [first.json()["id"], second.json()["id"]]) <= SENT


def test_requests_resumed_after_a_restart_count_as_waiting() -> None:
    store = MemoryRequestStore()
    left = []
    for _ in range(2):  # a previous run stopped while these were being decided
        record, _ = store.create_request("app-a", Task.model_validate(TASK).model_dump(mode="json"))
        store.transition(record.id, "selecting")
        left.append(record.id)
    held = Held()
    app = create_app(
        Settings(cloud="cloud-a", api_keys={"key-a": "app-a"}, max_waiting=2, busy_after=3600.0),
        store=store,
        link=MemoryRobotLink("cloud-a", [robot(i) for i in range(20)], offline_after=3600),
        selector=held,
    )
    with TestClient(app) as client:
        try:
            refused = client.post("/v1/requests", json=TASK, headers=A)
            assert refused.status_code == 503, refused.text
            assert refused.json()["detail"].startswith(
                "this cloud is busy: 2 requests are waiting for their robots"
            )
        finally:
            held.gate.set()
        assert settled(client, left) <= SENT
        assert client.post("/v1/requests", json=TASK, headers=A).status_code == 202
