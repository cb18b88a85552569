"""Two IaaSs in one process on real Zenoh routers (loopback): what one says of the other's
requests and capabilities (issue 26)."""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Iterator
from typing import Any

import pytest
import zenoh
from fastapi.testclient import TestClient

from loopback_ports import free_port
from robocloud.fleet import keys, open_client
from robocloud.iaas.app import create_app
from robocloud.iaas.config import Settings
from robocloud.storage import MemoryRequestStore
from waiting import wait_until

KEY = {"Authorization": "Bearer key-1"}


def robot_state(robot_id: str, capability: str, seq: int) -> bytes:
    """A robot's state as protocol 1.1 says, written here by hand (not the product's codec)."""
    return json.dumps({
        "id": robot_id, "cloud": "cloud-b", "kind": "tribot", "position": [0.0, 0.0],
        "speed": 1.0, "battery": 80.0, "status": "idle", "travel_cost_per_m": 0.1,
        "capabilities": {capability: {"kind": "actuating", "time": 60.0, "cost": 5.0}},
        "task": None, "seq": seq, "sent_at": time.time(),
    }).encode()


@pytest.fixture
def two_clouds() -> Iterator[tuple[TestClient, TestClient, int, zenoh.Session]]:
    a_zenoh, b_zenoh, a_port = free_port(), free_port(), free_port()
    common: dict[str, Any] = {"api_keys": {"key-1": "app-1"}, "selection_workers": 0,
                              "gather_timeout": 1.0}
    a = Settings(cloud="cloud-a", port=a_port, zenoh_listen=(f"tcp/127.0.0.1:{a_zenoh}",),
                 **common)
    b = Settings(cloud="cloud-b", port=free_port(), zenoh_listen=(f"tcp/127.0.0.1:{b_zenoh}",),
                 zenoh_peers=(f"tcp/127.0.0.1:{a_zenoh}",), **common)
    with contextlib.ExitStack() as stack:
        client_a = stack.enter_context(TestClient(create_app(a, store=MemoryRequestStore())))
        client_b = stack.enter_context(TestClient(create_app(b, store=MemoryRequestStore())))
        robot = open_client([f"tcp/127.0.0.1:{b_zenoh}"])
        stack.callback(robot.close)
        wait_until(lambda: all(
            len(c.get("/v1/clouds", headers=KEY).json()) == 2 for c in (client_a, client_b)),
            10.0, "each cloud to see the other")
        yield client_a, client_b, a_port, robot


def test_a_request_asked_for_at_another_cloud_names_its_cloud_and_capabilities_are_federated(
    two_clouds: tuple[TestClient, TestClient, int, zenoh.Session],
) -> None:
    at_a, at_b, a_port, robot = two_clouds
    # A robot of cloud-b announces "water"; cloud-a has none.
    robot.put(keys.state_key("cloud-b", "b-0001"), robot_state("b-0001", "water", 1))
    wait_until(
        lambda: at_b.get("/healthz").json()["robots"] == 1, 10.0, "cloud-b to hear its robot"
    )
    task = {"location": [0.0, 0.0], "actuating": {"water": 1}, "max_robots": 1,
            "max_cost": 100.0, "max_time": 1.0}  # too short for the robot: rejected at once
    answer = at_a.post("/v1/requests", json=task, headers=KEY)
    assert answer.status_code == 202, answer.text  # cloud-a knows "water" from cloud-b's info
    rid = answer.json()["id"]
    refused = at_a.post("/v1/requests", json={**task, "actuating": {"lava": 1}}, headers=KEY)
    assert refused.status_code == 422
    assert refused.json()["detail"] == (
        "actuating.lava: no robot of the federation has announced the capability 'lava', so "
        "none could serve this task; the capabilities announced are water."
    )

    # At cloud-b, cloud-a's request: a 404 naming cloud-a and its API, for every way in.
    for method, path in (("GET", f"/v1/requests/{rid}"), ("GET", f"/v1/requests/{rid}/events"),
                         ("POST", f"/v1/requests/{rid}/cancel")):
        elsewhere = at_b.request(method, path, headers=KEY)
        assert elsewhere.status_code == 404, (path, elsewhere.text)
        assert elsewhere.json()["detail"] == (
            f"there is no request '{rid}' at cloud-b: it is held by cloud-a (its API: "
            f"http://127.0.0.1:{a_port}), the cloud whose IaaS received it; ask there, with a "
            "key it accepts."
        )
    assert at_a.get(f"/v1/requests/{rid}", headers=KEY).json()["state"] == "rejected"
    # A request no cloud holds: the plain 404.
    unknown = at_b.get("/v1/requests/req-aaaaaaaaaaaa", headers=KEY)
    assert unknown.status_code == 404
    assert unknown.json()["detail"] == "there is no request 'req-aaaaaaaaaaaa'."
