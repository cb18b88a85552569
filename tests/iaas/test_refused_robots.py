"""A robot whose states are refused is listed with the reason, not silently offline (issue 25).

Over the HTTP API with the in-memory robot link, whose ``refusals`` stand for
what ``ZenohRobotLink`` keeps (tested on real Zenoh in
``tests/fleet/test_zenoh_link.py``); and the bound on how many are kept.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
from fastapi.testclient import TestClient

from robocloud.domain import Robot
from robocloud.fleet import MemoryRobotLink
from robocloud.fleet.state_errors import MAX_TRACKED, StateErrors
from robocloud.iaas.app import create_app
from robocloud.iaas.config import Settings
from robocloud.storage import MemoryRequestStore

A = {"Authorization": "Bearer key-a"}
AHEAD = "sent_at: the state was sent at 1764680000.000, 900 s ahead of this IaaS's clock."


def robot(i: int) -> Robot:
    return Robot.model_validate(
        {
            "id": f"a-{i:04d}", "cloud": "cloud-a", "position": [1.0, 0.0], "speed": 1.0,
            "battery": 90.0, "status": "idle", "travel_cost_per_m": 0.1,
            "capabilities": {"grabber": {"kind": "actuating", "time": 5.0, "cost": 1.0}},
        }
    )


@pytest.fixture
def fleet() -> MemoryRobotLink:
    return MemoryRobotLink("cloud-a", [robot(1), robot(2)], offline_after=3600.0)


@pytest.fixture
def client(fleet: MemoryRobotLink) -> Iterator[TestClient]:
    settings = Settings(cloud="cloud-a", api_keys={"key-a": "app-a"}, selection_workers=0)
    with TestClient(create_app(settings, store=MemoryRequestStore(), link=fleet)) as c:
        yield c


def listed(client: TestClient, query: str = "") -> dict[str, dict[str, Any]]:
    answer = client.get(f"/v1/robots{query}", headers=A)
    assert answer.status_code == 200
    return {r["id"]: r for r in answer.json()}


def test_refused_robots_are_listed_with_the_reason(
    client: TestClient, fleet: MemoryRobotLink
) -> None:
    assert all(r["refused"] is None for r in listed(client).values())
    fleet.refusals["a-0002"] = AHEAD  # heard before, its states refused now
    fleet.refusals["a-0009"] = AHEAD  # never accepted at all
    robots = listed(client)
    assert robots["a-0002"]["refused"] == AHEAD and robots["a-0001"]["refused"] is None
    assert robots["a-0009"]["refused"] == AHEAD
    assert robots["a-0009"]["status"] == "offline" and robots["a-0009"]["capabilities"] == []
    assert list(robots) == ["a-0001", "a-0002", "a-0009"]
    assert client.get("/v1/robots", headers=A).headers["x-total-count"] == "3"
    # Filters apply: it has no capability and is offline.
    assert "a-0009" not in listed(client, "?capability=grabber")
    assert "a-0009" in listed(client, "?status=offline")
    assert "a-0009" not in listed(client, "?cloud=cloud-b")
    del fleet.refusals["a-0002"], fleet.refusals["a-0009"]
    robots = listed(client)
    assert robots["a-0002"]["refused"] is None and "a-0009" not in robots


class Puts:
    """Stands for a Zenoh session: records what the refusals answer."""

    def __init__(self) -> None:
        self.put_count = 0

    def put(self, *_args: object, **_kwargs: object) -> None:
        self.put_count += 1


def test_refusals_keep_one_reason_a_robot_and_a_bounded_count() -> None:
    errors = StateErrors(Puts(), "cloud-a")  # type: ignore[arg-type]
    errors.refuse("robocloud/cloud-a/robots/a-1/state", "battery", "battery: first.")
    errors.refuse("robocloud/cloud-a/robots/a-1/state", "sent_at", "sent_at: second.")
    assert errors.refused() == {"a-1": "sent_at: second."}
    for i in range(MAX_TRACKED + 50):
        errors.in_batch("robocloud/cloud-a/fleets/gw/states", f"u-{i}", "sent_at", "late.")
    refused = errors.refused()
    assert len(refused) == MAX_TRACKED and refused["a-1"] == "sent_at: second."
    errors.refuse("robocloud/cloud-a/robots/a-1/state", "id", "id: third.")
    assert errors.refused()["a-1"] == "id: third."  # a robot kept is still told anew
    errors.accepted(["a-1", "u-0"])
    assert "a-1" not in errors.refused() and len(errors.refused()) == MAX_TRACKED - 2
