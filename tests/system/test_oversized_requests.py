"""Oversized requests next to normal ones on a live IaaS (issue 9's proof).

The request that used to freeze a whole cloud (``{"grabber": 10000}``,
``max_robots`` 100,000) is now refused at POST; one within the bounds but
beyond the fleet is answered at once with its reason; the largest coalition
the fleet allows is selected in a worker process while a normal request,
sent right after it, is dispatched within 3 s. The IaaS's memory stays small.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from processes import Cloud, follow

NORMAL: dict[str, Any] = {
    "location": [1000.0, 1000.0],
    "actuating": {"grabber": 1},
    "max_robots": 2,
    "max_cost": 10_000.0,
    "max_time": 100_000.0,
    "priority": "time",
}
HUGE = {"max_robots": 100_000, "max_cost": 1e12, "max_time": 1e9, "min_battery": 0.0}
SENT = {"dispatched", "underway", "completed"}


@pytest.fixture
def cloud(tmp_path: Path) -> Iterator[Cloud]:
    cloud = Cloud("cloud-a", tmp_path, f"sqlite:///{tmp_path / 'a.db'}", robots=300, speedup=5.0)
    try:
        yield cloud.start()
    finally:
        cloud.stop()


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise AssertionError(f"no VmRSS for {pid}")


def idle_by_capability(robots: list[dict[str, Any]]) -> dict[tuple[str, str], int]:
    counts: dict[tuple[str, str], int] = {}
    for robot in robots:
        if robot["status"] == "idle":
            for name, kind in robot["capability_kinds"].items():
                counts[kind, name] = counts.get((kind, name), 0) + 1
    return counts


def dispatched_within(client: Any, task: dict[str, Any], seconds: float) -> float:
    """POST ``task`` and follow it until dispatched: the seconds it took (asserted)."""
    posted = time.monotonic()
    answer = client.post("/v1/requests", json=task)
    assert answer.status_code == 202, answer.text
    body = follow(client, answer.json()["id"], lambda b: b["state"] in SENT | {"rejected"},
                  seconds, "the normal request to be dispatched")
    assert body["state"] in SENT, body
    return time.monotonic() - posted


def test_an_oversized_request_never_holds_up_a_normal_one(cloud: Cloud) -> None:
    assert cloud.iaas is not None
    with cloud.client() as client:
        # The request of the issue: refused at POST, naming the count.
        answer = client.post("/v1/requests", json={
            **NORMAL, **HUGE, "actuating": {"grabber": 10_000}})
        assert answer.status_code == 422
        assert "grabber" in answer.json()["detail"]

        robots = client.get("/v1/robots").json()
        idle = idle_by_capability(robots)
        # Within the bounds, beyond the fleet: answered at once, with the reason.
        beyond: dict[str, Any] = {**NORMAL, **HUGE, "sensing": {}, "actuating": {}}
        for kind, name in idle:
            beyond[kind][name] = 1000
        answer = client.post("/v1/requests", json=beyond)
        assert answer.status_code == 202, answer.text
        body = follow(client, answer.json()["id"], lambda b: b["state"] == "rejected", 3.0,
                      "the request beyond the fleet to be rejected")
        assert "needs 1,000 robots, but only" in body["reason"], body["reason"]
        took = dispatched_within(client, NORMAL, 3.0)

        # The largest coalition this fleet allows, every capability at once, then a
        # normal request: the normal one does not wait for the large selection.
        large: dict[str, Any] = {**NORMAL, **HUGE, "sensing": {}, "actuating": {}}
        for (kind, name), count in idle.items():
            large[kind][name] = max(1, count // 4)
        needed = sum(large["sensing"].values()) + sum(large["actuating"].values())
        answer = client.post("/v1/requests", json=large)
        assert answer.status_code == 202, answer.text
        took = max(took, dispatched_within(client, NORMAL, 3.0))
        body = follow(client, answer.json()["id"],
                      lambda b: b["state"] in SENT | {"rejected", "failed"}, 30.0,
                      "the large request to be decided")
        assert body["state"] in SENT, body
        assert len(body["coalition"]) >= max(large["actuating"].values())
        assert needed >= 30  # large indeed: a coalition of dozens of robots
    # The selections ran in worker processes; the IaaS itself stayed small.
    assert rss_mb(cloud.iaas.pid) < 400, rss_mb(cloud.iaas.pid)
    assert took < 3.0
