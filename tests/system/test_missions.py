"""Missions carried out by real processes: two clouds (IaaS, Zenoh router, simulator each).

A 5-fire mission with precedence needs grabbers of both clouds; a robot whose
battery dies mid-mission is replaced by a re-plan and the mission completes;
a DELETE stops every robot of a mission.

The tests share one pair of clouds (started once, about a third of the
file's time): each leaves it as it found it, no mission open and every robot
of its missions idle (``settled`` cancels what a failed test left). The
simulator runs at ``SPEEDUP``: a plan of 1,600 robot seconds is carried out in
8 s. The re-plan test runs first, on the fleet as drawn (its robots start far
from the fires), and kills the robot on its way whose task starts last
(210 to 580 robot seconds into the plans seen), through a router session
opened beforehand: the fault landed 5 to 25 robot seconds after the plan.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from processes import Cloud, start_clouds, wait_until

NAMES = ("cloud-a", "cloud-b")
FINAL = ("completed", "rejected", "failed", "canceled")
# Robot seconds per wall second. The watchdog's floor is wall time (30 s),
# so no robot is late for it at any speed-up.
SPEEDUP = 200.0
# Per cloud: with these seeds, 4 and 7 idle grabbers of 33 % battery or more,
# enough for the three missions in turn (30 robots drew 1 and 3).
ROBOTS = 40


@pytest.fixture(scope="module")
def clouds(tmp_path_factory: pytest.TempPathFactory) -> Iterator[list[Cloud]]:
    # No selection workers (a mission's planner is a child of its own): two fewer
    # processes per IaaS to start on a shared machine.
    started = start_clouds(tmp_path_factory.mktemp("missions"), NAMES, robots=ROBOTS,
                           speedup=SPEEDUP, iaas_args=lambda name: ["--selection-workers", "0"])
    try:
        yield started
    finally:
        for cloud in started:
            cloud.stop()


@pytest.fixture(autouse=True)
def settled(clouds: list[Cloud]) -> Iterator[None]:
    """After a test that failed midway: its missions canceled, their robots idle.

    (A test that passes waits for its own robots.)"""
    yield
    held: set[str] = set()
    for cloud in clouds:
        with cloud.client() as client:
            for mission in client.get("/v1/missions", params={"limit": 200}).json()["missions"]:
                if mission["state"] not in FINAL:
                    canceled = client.delete(f"/v1/missions/{mission['id']}").json()
                    held |= {r["id"] for r in (canceled["plan"] or {}).get("robots", [])
                             if r["state"] != "failed"}
    if held:
        with clouds[0].client() as client:
            wait_until(lambda: robots_idle(client, held), 30, "the canceled missions' robots idle")


@pytest.fixture
def routers(clouds: list[Cloud]) -> Iterator[dict[str, Any]]:
    """A Zenoh client session to each cloud's router, by cloud, open before the test's
    mission: a fault then lands in hundredths of a second, not tenths."""
    from robocloud.fleet import open_client

    sessions = {c.name: open_client([c.zenoh], timeout=5.0) for c in clouds}
    try:
        yield sessions
    finally:
        for session in sessions.values():
            session.close()


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
        "time_limit": 1,
    }


def follow_mission(
    client: httpx.Client, mission_id: str, until: Any, timeout: float, what: str,
    every: float = 0.1,
) -> dict[str, Any]:
    def check() -> dict[str, Any] | None:
        body: dict[str, Any] = client.get(f"/v1/missions/{mission_id}").json()
        return body if until(body) else None

    found: dict[str, Any] = wait_until(check, timeout, what, every=every)
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


def next_start(mission: dict[str, Any], robot: dict[str, Any]) -> float:
    """When (plan time) the robot's next task not started yet starts."""
    tasks = {t["id"]: t for t in mission["plan"]["tasks"]}
    return min((leg["start"] for leg in robot["legs"]
                if tasks[leg["task"]]["state"] in ("pending", "travel", "waiting")), default=0.0)


def test_a_robot_that_dies_is_replanned_around(clouds: list[Cloud],
                                               routers: dict[str, Any]) -> None:
    with clouds[0].client() as client:
        body = five_fires(client, first=1)
        mission_id = client.post("/v1/missions", json=body).json()["id"]

        def travelling(m: dict[str, Any]) -> bool:
            if m["state"] in FINAL:
                return True
            return m["plan"] is not None and any(
                r["state"] == "travel" for r in m["plan"]["robots"]
            )

        underway = follow_mission(client, mission_id, travelling, 60, "a robot on its way",
                                  every=0.02)
        assert underway["state"] == "underway", underway["history"]
        # Of the robots on their way, the one whose task starts last: its fault lands
        # while it travels or waits there, not once it works (the file's SPEEDUP).
        victim = max((r for r in underway["plan"]["robots"] if r["state"] == "travel"),
                     key=lambda r: next_start(underway, r))
        home = next(c for c in clouds if c.name == victim["cloud"])
        assert home.fault(victim["id"], "battery", session=routers[home.name])["ok"]
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
        planned = next(h["at"] for h in replanned["history"] if h["state"] == "underway")
        print(f"re-plan: {again - died:.2f} s from the robot's failure to the new plan; it "
              f"died {(died - planned) * SPEEDUP:.0f} robot s after the plan was made, its task "
              f"was to start at {next_start(underway, victim):.0f} s")
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
        ids = {r["id"] for r in done["plan"]["robots"] if r["state"] != "failed"}
        wait_until(lambda: robots_idle(client, ids), 10, "the mission's other robots idle")


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
        # A bound, not a claim: a stopped robot shows its canceled task for 3 s.
        wait_until(lambda: robots_idle(client, ids), 10, "every robot of the mission idle")
        after = client.get(f"/v1/missions/{mission_id}").json()
        assert all(r["state"] in ("released", "failed") for r in after["plan"]["robots"])
        assert client.get("/v1/missions/mis-aaaaaaaaaaaa").status_code == 404
