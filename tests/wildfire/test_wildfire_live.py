"""The live model alone: deltas, staleness, clouds' health and alerts, with a hand-held clock."""

from __future__ import annotations

import random
from datetime import UTC, datetime
from typing import Any

from fake_iaas import robot

from robocloud.wildfire.config import WildfireSettings
from robocloud.wildfire.live import (
    CLOUD_COLOURS,
    ROBOT_COLUMNS,
    LiveModel,
    cloud_colour,
    fmt_duration,
)

T0 = 1_800_000_000.0


def model(**changes: Any) -> LiveModel:
    settings = WildfireSettings(iaas=("http://cloud-a.test", "http://cloud-b.test"),
                                stale_after=5.0, **changes)
    return LiveModel(settings, started=T0)


def endpoint(cloud: str, ok: bool | None = True) -> dict[str, Any]:
    return {"url": f"http://{cloud}.test", "cloud": cloud, "ok": ok, "since": T0, "error":
            None if ok else "the IaaS at x cannot be reached (Connection refused).",
            "time_scale": 10.0}


def iso(at: float) -> str:
    return datetime.fromtimestamp(at, UTC).isoformat()


class Page:
    """What a page holds, kept by the snapshot and the deltas as js/live.js keeps it."""

    def __init__(self, snapshot: dict[str, Any]) -> None:
        self.columns = snapshot["robots"]["columns"]
        self.robots = {row[0]: list(row) for row in snapshot["robots"]["rows"]}

    def apply(self, delta: dict[str, Any]) -> None:
        robots = delta.get("robots", {})
        for row in robots.get("add", []):
            self.robots[row[0]] = list(row)
        for change in robots.get("set", []):
            for i in range(1, len(change), 2):
                self.robots[change[0]][change[i]] = change[i + 1]
        for robot_id in robots.get("del", []):
            del self.robots[robot_id]


def test_a_page_kept_by_deltas_sees_what_a_new_page_sees() -> None:
    live = model()
    live.ingest_endpoints([endpoint("cloud-a")], 10.0)
    rng = random.Random(4)
    fleet = [robot(f"a-{i:04d}", "cloud-a", position=(rng.uniform(0, 2000), 0.0))
             for i in range(40)]
    live.ingest_fleet(fleet, T0)
    live.publish(T0)
    page = Page(live.snapshot(T0))
    for tick in range(1, 30):
        now = T0 + tick
        for r in rng.sample(fleet, 10):
            r["position"] = [rng.uniform(0, 2000), rng.uniform(0, 2000)]
            r["battery"] = rng.uniform(0, 100)
            r["status"] = rng.choice(["idle", "busy", "charging"])
        listed = fleet if tick % 7 else fleet[:30]  # now and then ten go quiet
        live.ingest_fleet(listed, now)
        page.apply(live.publish(now))
        assert page.robots == Page(live.snapshot(now)).robots


def test_a_delta_carries_only_what_changed() -> None:
    live = model()
    live.ingest_endpoints([endpoint("cloud-a")], 10.0)
    fleet = [robot("a-0001", "cloud-a"), robot("a-0002", "cloud-a")]
    live.ingest_fleet(fleet, T0)
    first = live.publish(T0)
    assert [row[0] for row in first["robots"]["add"]] == ["a-0001", "a-0002"]
    live.ingest_fleet(fleet, T0 + 1)
    assert "robots" not in live.publish(T0 + 1), "nothing moved: no robot in the delta"
    fleet[0]["position"] = [150.4, 200.0]
    fleet[0]["battery"] = 79.6  # rounds to 80, as before: not news
    live.ingest_fleet(fleet, T0 + 2)
    x = ROBOT_COLUMNS.index("x")
    assert live.publish(T0 + 2)["robots"] == {"set": [["a-0001", x, 150]]}


def test_a_robot_not_heard_goes_stale_with_its_age_then_is_forgotten() -> None:
    live = model()
    live.ingest_fleet([robot("a-0001", "cloud-a"), robot("a-0002", "cloud-a", seen_ago=0.0)],
                      T0)
    live.ingest_endpoints([endpoint("cloud-a")], 10.0)
    live.publish(T0)
    heard = ROBOT_COLUMNS.index("heard")
    live.ingest_fleet([robot("a-0002", "cloud-a", seen_ago=0.0)], T0 + 4)
    assert "robots" not in live.publish(T0 + 4)
    live.ingest_fleet([robot("a-0002", "cloud-a", seen_ago=0.0)], T0 + 6)
    delta = live.publish(T0 + 6)
    assert delta["robots"]["set"] == [["a-0001", heard, round(T0 - 0.1, 1)]]
    offers = {o["name"]: o for o in live.capability_offers(T0 + 6)}
    assert offers["grabber"] == {"name": "grabber", "kind": "actuating", "robots": 2, "idle": 1}
    # Heard again: fresh.
    live.ingest_fleet([robot("a-0001", "cloud-a")], T0 + 7)
    assert live.publish(T0 + 7)["robots"]["set"] == [["a-0001", heard, None]]
    # Silent for a quarter of an hour: gone from the page.
    live.ingest_fleet([robot("a-0002", "cloud-a", seen_ago=0.0)], T0 + 7 + 900)
    assert live.publish(T0 + 7 + 900.5)["robots"]["del"] == ["a-0001"]


def test_a_cloud_whose_iaas_stops_is_down_its_robots_stale_at_once() -> None:
    live = model()
    listing = [{"cloud": "cloud-a", "robots": 1, "idle": 1, "offline": 0},
               {"cloud": "cloud-b", "robots": 1, "idle": 1, "offline": 0}]
    fleet = [robot("a-0001", "cloud-a"), robot("b-0001", "cloud-b")]
    live.ingest_endpoints([endpoint("cloud-a"), endpoint("cloud-b")], 10.0)
    live.ingest_fleet(fleet, T0)
    live.ingest_clouds(listing, T0)
    first = live.publish(T0)
    assert "alerts" not in first, "clouds there from the start are not news"
    assert [(c["name"], c["status"]) for c in first["clouds"]] == [("cloud-a", "up"),
                                                                  ("cloud-b", "up")]
    # cloud-b's IaaS stops answering: down at the next tick, its robot greyed.
    live.ingest_endpoints([endpoint("cloud-a"), endpoint("cloud-b", ok=False)], 10.0)
    live.ingest_fleet(fleet[:1], T0 + 1)
    live.ingest_clouds(listing, T0 + 1)
    delta = live.publish(T0 + 1)
    heard = ROBOT_COLUMNS.index("heard")
    assert delta["robots"]["set"] == [["b-0001", heard, round(T0 - 0.1, 1)]]
    [alert] = delta["alerts"]
    assert alert["level"] == "danger" and alert["cloud"] == "cloud-b"
    assert alert["text"] == ("cloud-b is down: its IaaS at http://cloud-b.test does not answer. "
                             "Its 1 robot are greyed with the time since last heard.")
    # Back: one alert, the robot fresh again.
    live.ingest_endpoints([endpoint("cloud-a"), endpoint("cloud-b")], 10.0)
    live.ingest_fleet(fleet, T0 + 2)
    delta = live.publish(T0 + 2)
    assert [a["text"] for a in delta["alerts"]] == ["cloud-b is back: its robots report again."]
    assert delta["robots"]["set"] == [["b-0001", heard, None]]


def test_a_cloud_that_leaves_the_federation_is_down() -> None:
    live = model()
    live.ingest_endpoints([endpoint("cloud-a")], 10.0)
    live.ingest_clouds([{"cloud": "cloud-a"}, {"cloud": "cloud-c"}], T0)
    live.publish(T0)
    live.ingest_clouds([{"cloud": "cloud-a"}], T0 + 1)
    delta = live.publish(T0 + 1)
    assert [a["text"] for a in delta["alerts"]] == [
        "cloud-c is down: it left the federation. Its 0 robots are greyed with the time since "
        "last heard."]
    # A cloud first seen long after the start joined.
    live.ingest_clouds([{"cloud": "cloud-a"}, {"cloud": "cloud-c"}, {"cloud": "cloud-d"}],
                       T0 + 60)
    texts = [a["text"] for a in live.publish(T0 + 60)["alerts"]]
    assert texts == ["cloud-c is back: its robots report again.",
                     "cloud-d joined the federation."]


def test_no_iaas_answering_is_one_alert_and_every_cloud_unknown() -> None:
    live = model()
    live.ingest_endpoints([endpoint("cloud-a"), endpoint("cloud-b")], 10.0)
    live.ingest_clouds([{"cloud": "cloud-a"}, {"cloud": "cloud-b"}], T0)
    live.publish(T0)
    live.ingest_endpoints([endpoint("cloud-a", False), endpoint("cloud-b", False)], None)
    delta = live.publish(T0 + 10)
    texts = [a["text"] for a in delta["alerts"]]
    assert texts[0].startswith("No IaaS answers")
    assert {c["status"] for c in delta["clouds"]} == {"down"}


def request_record(at: float, history: list[dict[str, Any]], **fields: Any) -> dict[str, Any]:
    return {"id": "req-1", "label": "ridge", "state": "underway", "reason": None,
            "created_at": iso(at), "updated_at": iso(at), "task": {"location": [1, 2],
            "actuating": {"grabber": 1}, "max_time": 600.0}, "time": 300.0, "cost": 12.5,
            "coalition": [{"robot": "a-0001", "cloud": "cloud-a", "capabilities": ["grabber"],
                           "time": 300.0, "cost": 12.5}], "history": history, **fields}


def test_what_happens_to_a_followed_request_is_alerted_once() -> None:
    live = model()
    old = {"kind": "event", "state": "underway", "at": iso(T0 - 60),
           "detail": "robot a-0009 failed: its battery died"}
    live.ingest_request(request_record(T0 - 100, [old]), "cloud-a", T0)
    assert "alerts" not in live.publish(T0), "what happened before the start is history"
    failed = {"kind": "event", "state": "underway", "at": iso(T0 + 5),
              "detail": "robot a-0001 failed: its battery died"}
    replaced = {"kind": "event", "state": "underway", "at": iso(T0 + 5),
                "detail": "robot a-0001 replaced by b-0007"}
    record = request_record(T0 - 100, [old, failed, replaced], time=420.0, cost=30.0)
    live.ingest_request(record, "cloud-a", T0 + 6)
    live.ingest_request(record, "cloud-a", T0 + 7)  # read again: nothing new
    delta = live.publish(T0 + 7)
    assert [(a["level"], a["text"]) for a in delta["alerts"]] == [
        ("warning", "Request “ridge” (req-1): robot a-0001 failed: its battery died."),
        ("info", "Request “ridge” (req-1): robot a-0001 replaced by b-0007. The coalition's "
                 "time is now 7 min 00 s robot time, its cost 30.00 credits."),
    ]
    assert [r["id"] for r in delta["requests"]] == ["req-1"]
    assert delta["requests"][0]["time"] == 420.0
    ended = {"kind": "state", "state": "failed", "at": iso(T0 + 9),
             "detail": "no replacement for a-0001"}
    live.ingest_request(request_record(T0 - 100, [old, failed, replaced, ended],
                                       state="failed"), "cloud-a", T0 + 9)
    [alert] = live.publish(T0 + 9)["alerts"]
    assert alert == {"id": 3, "at": T0 + 9, "level": "danger", "kind": "request",
                     "text": "Request “ridge” (req-1) failed: no replacement for a-0001.",
                     "cloud": None, "request": "req-1"}
    assert live.active_requests() == []


def test_cloud_colours_are_stable_and_distinct() -> None:
    names = ["cloud-a", "cloud-b", "cloud-c"]
    first = {n: cloud_colour(n, set()) for n in names}
    assert len(set(first.values())) == 3
    for order in (names, names[::-1]):
        live = model()
        live.ingest_clouds([{"cloud": n} for n in order], T0)
        assert {c["name"]: c["colour"] for c in live.clouds_json()} == first
    # Eight clouds get the eight colours; a ninth shares one rather than failing.
    taken: set[str] = set()
    for i in range(8):
        taken.add(cloud_colour(f"c{i}", taken))
    assert taken == set(CLOUD_COLOURS)
    assert cloud_colour("c9", taken) in CLOUD_COLOURS


def test_malformed_robots_are_skipped_not_trusted() -> None:
    live = model()
    live.ingest_fleet([None, {"id": 3}, {"id": "x", "cloud": "c", "position": [1]},
                       {"id": "y", "cloud": "c", "position": ["a", 2]},
                       robot("a-0001", "cloud-a") | {"status": "exploding", "battery": "full"}],
                      T0)
    [row] = live.snapshot(T0)["robots"]["rows"] or live.publish(T0)["robots"]["add"]
    assert row[:3] == ["a-0001", "cloud-a", "offline"] and row[5] == 0


def test_one_duration_format() -> None:
    assert [fmt_duration(s) for s in (0.4, 42, 65, 3599, 3600, 7500)] == [
        "under 1 s", "42 s", "1 min 05 s", "59 min 59 s", "1 h 00 min", "2 h 05 min"]
