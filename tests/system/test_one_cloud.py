"""One cloud end to end with real processes: an IaaS and a simulated fleet on loopback.

Robots run 300 times faster than the clock (``--speedup``), so a task of a few
hundred seconds completes in a second or two, while the robots that a test
cancels or whose battery it kills (seed 0's, driving 630 s of robot time or
more: over 2 s) are still on their way when it does. The PostgreSQL test,
which catches no robot on its way, runs them 1,000 times faster.
"""

from __future__ import annotations

import concurrent.futures
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from processes import NO_SHEDDING, Cloud, follow, wait_until

TASK: dict[str, Any] = {
    "location": [1000.0, 1000.0],
    "sensing": {"sound": 1},
    "actuating": {"grabber": 1},
    "max_robots": 3,
    "max_cost": 1000.0,
    "max_time": 3000.0,
    "min_battery": 20.0,
    "priority": "time",
}


@pytest.fixture(scope="module")
def shared_cloud(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cloud]:
    """One cloud for the tests that need nothing special (a start is 4-5 s of two cores)."""
    tmp_path = tmp_path_factory.mktemp("one-cloud")
    cloud = Cloud(
        "cloud-a", tmp_path, f"sqlite:///{tmp_path / 'cloud-a.db'}", robots=50, speedup=300.0
    )
    try:
        yield cloud.start()
    finally:
        cloud.stop()


@pytest.fixture
def cloud(shared_cloud: Cloud) -> Iterator[Cloud]:
    """The shared cloud; after the test, its IaaS up, no request open, every robot free."""
    try:
        yield shared_cloud
    finally:
        shared_cloud.settle()


def robots_of(request: dict[str, Any]) -> list[str]:
    return [a["robot"] for a in request["coalition"] or []]


def test_request_is_served_to_completion(cloud: Cloud) -> None:
    with cloud.client() as client:
        answer = client.post("/v1/requests", json=TASK)
        assert answer.status_code == 202
        rid = answer.json()["id"]
        done = follow(
            client,
            rid,
            lambda r: r["state"] in ("completed", "failed", "rejected"),
            60,
            "the request to finish",
        )
        assert done["state"] == "completed", done
        states = [h["state"] for h in done["history"] if h["kind"] == "state"]
        assert states == ["received", "selecting", "dispatched", "underway", "completed"]
        assert all(a["progress"]["phase"] == "done" for a in done["coalition"])
        robots = {r["id"]: r for r in client.get("/v1/robots").json()}
        for robot in robots_of(done):
            assert robots[robot]["position"] == pytest.approx(TASK["location"])
            assert robots[robot]["request"] is None


def test_cancel_stops_every_robot(cloud: Cloud) -> None:
    with cloud.client() as client:
        rid = client.post("/v1/requests", json={**TASK, "actuating": {"grabber": 2}}).json()["id"]
        underway = follow(client, rid, lambda r: r["state"] == "underway", 20, "underway")
        canceled = client.post(f"/v1/requests/{rid}/cancel")
        assert canceled.status_code == 200 and canceled.json()["state"] == "canceled"

        def stopped() -> bool:
            robots = {r["id"]: r for r in client.get("/v1/robots").json()}
            return all(
                robots[i]["status"] == "idle" and robots[i]["request"] is None
                for i in robots_of(underway)
            )

        wait_until(stopped, 10, "the canceled robots to be idle and free")
        assert client.post(f"/v1/requests/{rid}/cancel").status_code == 200


def test_a_robot_whose_battery_dies_is_replaced(cloud: Cloud) -> None:
    with cloud.client() as client:
        rid = client.post("/v1/requests", json=TASK).json()["id"]
        underway = follow(client, rid, lambda r: r["state"] == "underway", 20, "underway")
        victim = robots_of(underway)[0]
        assert cloud.fault(victim, "battery")["ok"] is True
        done = follow(
            client,
            rid,
            lambda r: r["state"] in ("completed", "failed"),
            60,
            "the request to finish after the failure",
        )
        details = [h["detail"] or "" for h in done["history"]]
        assert any(f"robot {victim} failed" in d for d in details), details
        assert any(f"robot {victim} replaced by" in d for d in details), details
        assert done["state"] == "completed", done
        assert victim not in robots_of(done)


def test_kill_9_and_restart_keeps_every_request(cloud: Cloud) -> None:
    with cloud.client() as client:
        finished = client.post("/v1/requests", json={**TASK, "actuating": {"grabber": 9}})
        follow(client, finished.json()["id"], lambda r: r["state"] == "rejected", 10, "reject")
        running = client.post("/v1/requests", json={**TASK, "location": [1900.0, 1900.0]})
        rid = running.json()["id"]
        follow(client, rid, lambda r: r["state"] == "underway", 20, "underway")
    cloud.kill_iaas()
    cloud.start_iaas()
    with cloud.client() as client:
        listed = {r["id"]: r for r in client.get("/v1/requests").json()["items"]}
        assert listed[finished.json()["id"]]["state"] == "rejected"
        assert [h["state"] for h in listed[rid]["history"]][:4] == [
            "received",
            "selecting",
            "dispatched",
            "underway",
        ]
        done = follow(
            client,
            rid,
            lambda r: r["state"] in ("completed", "failed"),
            60,
            "the resumed request to finish",
        )
        assert done["state"] == "completed", done
        assert any("restart" in (h["detail"] or "") for h in done["history"])
        assert all(r["request"] is None for r in client.get("/v1/robots").json())


def test_fifty_concurrent_requests_never_share_a_robot(tmp_path: Path) -> None:
    # Slow robots: nothing finishes while the requests are being served. Fifty
    # at once: load shedding would refuse some (503), not what this test is about.
    cloud = Cloud(
        "cloud-a", tmp_path, f"sqlite:///{tmp_path / 'race.db'}", robots=50, speedup=2.0,
        iaas_args=NO_SHEDDING,
    ).start()
    try:
        task = {**TASK, "max_robots": 2}

        def send(i: int) -> str:
            with httpx.Client(
                base_url=cloud.url, headers={"Authorization": "Bearer test-key"}, timeout=30
            ) as c:
                return str(c.post("/v1/requests", json={**task, "label": f"r{i}"}).json()["id"])

        with concurrent.futures.ThreadPoolExecutor(50) as pool:
            ids = list(pool.map(send, range(50)))
        with cloud.client() as client:

            def settled() -> list[dict[str, Any]] | None:
                got = [client.get(f"/v1/requests/{i}").json() for i in ids]
                return (
                    got if all(r["state"] not in ("received", "selecting") for r in got) else None
                )

            requests = wait_until(settled, 60, "every request to be selected")
            served = [r for r in requests if r["state"] in ("dispatched", "underway")]
            rejected = [r for r in requests if r["state"] == "rejected"]
            assert len(served) + len(rejected) == 50, [
                (r["state"], r["reason"])
                for r in requests
                if r["state"] not in ("rejected", "underway", "dispatched")
            ]
            assert served, "no request was served"
            held = [robot for r in served for robot in robots_of(r)]
            assert len(held) == len(set(held)), "a robot is in two active coalitions"
            assert all(r["reason"] for r in rejected)
            for r in served:
                client.post(f"/v1/requests/{r['id']}/cancel")
    finally:
        cloud.stop()


def test_postgresql_store(tmp_path: Path, postgres_url: str) -> None:
    cloud = Cloud("cloud-a", tmp_path, postgres_url, robots=20, speedup=1000.0).start()
    try:
        with cloud.client() as client:
            rid = client.post("/v1/requests", json=TASK).json()["id"]
            done = follow(
                client,
                rid,
                lambda r: r["state"] in ("completed", "failed"),
                60,
                "completion on PostgreSQL",
            )
            assert done["state"] == "completed"
        cloud.kill_iaas()
        cloud.start_iaas()
        with cloud.client() as client:
            assert client.get(f"/v1/requests/{rid}").json()["state"] == "completed"
    finally:
        cloud.stop()
