"""Missions carried out by real processes: two clouds (IaaS, Zenoh router, simulator each).

A 5-fire mission with precedence needs grabbers of both clouds; a robot whose
battery dies mid-mission is replaced by a re-plan and the mission completes;
a DELETE stops every robot of a mission.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from processes import Cloud, start_clouds, wait_until

NAMES = ("cloud-a", "cloud-b")
FINAL = ("completed", "rejected", "failed", "canceled")


@pytest.fixture
def clouds(tmp_path: Path) -> Iterator[list[Cloud]]:
    started = start_clouds(tmp_path, NAMES, robots=30, speedup=50.0)
    try:
        yield started
    finally:
        for cloud in started:
            cloud.stop()


def idle_grabbers(client: httpx.Client) -> list[dict[str, Any]]:
    robots = client.get("/v1/robots", params={"scope": "federation"}).json()
    return [
        r for r in robots
        if r["status"] == "idle" and "grabber" in r["capabilities"] and r["battery"] >= 30.0
    ]


def five_fires(client: httpx.Client, first: int | None = None) -> dict[str, Any]:
    """Five fires; unless ``first`` says how many grabbers fire-1 needs, it needs more
    than either cloud has idle: both serve it."""
    grabbers = idle_grabbers(client)
    per_cloud = {name: sum(r["cloud"] == name for r in grabbers) for name in NAMES}
    assert all(per_cloud.values()), per_cloud
    if first is None:
        first = min(max(per_cloud.values()) + 1, len(grabbers))
    else:
        assert len(grabbers) >= first + 2, "spare grabbers for a re-plan"
    fires = [[400.0, 400.0], [600.0, 500.0], [800.0, 300.0], [500.0, 800.0], [900.0, 900.0]]
    return {
        "label": "five fires",
        "tasks": [
            {"id": f"fire-{n}", "location": xy, "actuating": {"grabber": first if n == 1 else 1}}
            for n, xy in enumerate(fires, start=1)
        ],
        "precedence": [["fire-1", "fire-2"], ["fire-2", "fire-5"], ["fire-3", "fire-4"]],
        "min_battery": 30.0,
        "time_limit": 3,
    }


def follow_mission(
    client: httpx.Client, mission_id: str, until: Any, timeout: float, what: str
) -> dict[str, Any]:
    def check() -> dict[str, Any] | None:
        body: dict[str, Any] = client.get(f"/v1/missions/{mission_id}").json()
        return body if until(body) else None

    found: dict[str, Any] = wait_until(check, timeout, what, every=0.1)
    return found


def check_plan_order(mission: dict[str, Any]) -> None:
    """Every task done, none started before its predecessors ended (in plan times)."""
    tasks = {t["id"]: t for t in mission["plan"]["tasks"]}
    assert all(t["state"] == "done" for t in tasks.values()), tasks
    for before, after in mission["mission"]["precedence"]:
        assert tasks[after]["start"] >= tasks[before]["end"] - 1e-6, (before, after)


def robots_idle(client: httpx.Client, ids: set[str]) -> bool:
    robots = client.get("/v1/robots", params={"scope": "federation"}).json()
    mine = [r for r in robots if r["id"] in ids]
    return len(mine) == len(ids) and all(
        r["status"] == "idle" and (r.get("progress") is None
                                   or r["progress"]["phase"] in ("done", "failed"))
        for r in mine
    )


def test_five_fires_are_served_across_two_clouds(clouds: list[Cloud]) -> None:
    with clouds[0].client() as client:
        body = five_fires(client)
        posted = time.monotonic()
        answer = client.post("/v1/missions", json=body, headers={"Idempotency-Key": "fires-1"})
        assert answer.status_code == 202, answer.text
        mission_id = answer.json()["id"]
        assert answer.headers["Location"] == f"/v1/missions/{mission_id}"
        again = client.post("/v1/missions", json=body, headers={"Idempotency-Key": "fires-1"})
        assert again.json()["id"] == mission_id
        done = follow_mission(client, mission_id, lambda m: m["state"] in FINAL, 120, "the end")
        elapsed = time.monotonic() - posted
        assert done["state"] == "completed", done["history"]
        assert {r["cloud"] for r in done["plan"]["robots"]} == set(NAMES)
        assert all(r["state"] == "released" for r in done["plan"]["robots"])
        check_plan_order(done)
        print(f"five fires: POST to completed in {elapsed:.1f} s, "
              f"plan {done['plan']['makespan']:.0f} s robot time")
        ids = {r["id"] for r in done["plan"]["robots"]}
        wait_until(lambda: robots_idle(client, ids), 10, "the mission's robots idle")


def test_a_robot_that_dies_is_replanned_around(clouds: list[Cloud]) -> None:
    with clouds[0].client() as client:
        body = five_fires(client, first=1)
        mission_id = client.post("/v1/missions", json=body).json()["id"]

        def travelling(m: dict[str, Any]) -> bool:
            if m["state"] in FINAL:
                return True
            return m["plan"] is not None and any(
                r["state"] == "travel" for r in m["plan"]["robots"]
            )

        underway = follow_mission(client, mission_id, travelling, 60, "a robot on its way")
        assert underway["state"] == "underway", underway["history"]
        victim = next(r for r in underway["plan"]["robots"] if r["state"] == "travel")
        home = next(c for c in clouds if c.name == victim["cloud"])
        assert home.fault(victim["id"], "battery")["ok"]
        failed = f"robot {victim['id']} failed"
        replanned = follow_mission(
            client, mission_id,
            lambda m: any("re-planned" in h["note"] for h in m["history"]) or m["state"] in FINAL,
            30, "the re-plan",
        )
        assert any(failed in h["note"] for h in replanned["history"]), replanned["history"]
        assert replanned["plan"]["version"] >= 2, replanned["history"]
        died = next(h["at"] for h in replanned["history"] if failed in h["note"])
        again = next(h["at"] for h in replanned["history"] if "re-planned" in h["note"])
        print(f"re-plan: {again - died:.2f} s from the robot's failure to the new plan")
        done = follow_mission(client, mission_id, lambda m: m["state"] in FINAL, 120, "the end")
        assert done["state"] == "completed", done["history"]
        check_plan_order(done)
        dead = next(r for r in done["plan"]["robots"] if r["id"] == victim["id"])
        assert dead["state"] == "failed"
        # The tasks it had not started when it died went to others.
        ahead = {
            t["id"] for t in underway["plan"]["tasks"]
            if victim["id"] in t["robots"] and t["state"] in ("pending", "travel", "waiting")
        }
        assert ahead
        final = {t["id"]: t for t in done["plan"]["tasks"]}
        assert all(victim["id"] not in final[name]["robots"] for name in ahead)


def test_delete_stops_every_robot_of_the_mission(clouds: list[Cloud]) -> None:
    with clouds[0].client() as client:
        body = five_fires(client)
        mission_id = client.post("/v1/missions", json=body).json()["id"]
        underway = follow_mission(
            client, mission_id,
            lambda m: m["state"] in FINAL or (
                m["state"] == "underway"
                and sum(r["state"] in ("travel", "waiting") for r in m["plan"]["robots"]) >= 2
            ),
            60, "robots on their way",
        )
        assert underway["state"] == "underway", underway["history"]
        ids = {r["id"] for r in underway["plan"]["robots"]}
        canceled = client.delete(f"/v1/missions/{mission_id}")
        assert canceled.status_code == 200
        assert canceled.json()["state"] == "canceled"
        assert client.delete(f"/v1/missions/{mission_id}").json()["state"] == "canceled"
        wait_until(lambda: robots_idle(client, ids), 5, "every robot of the mission idle")
        after = client.get(f"/v1/missions/{mission_id}").json()
        assert all(r["state"] in ("released", "failed") for r in after["plan"]["robots"])
        assert client.get("/v1/missions/mis-aaaaaaaaaaaa").status_code == 404
