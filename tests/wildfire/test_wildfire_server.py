"""The wildfire server over fake IaaSs (httpx.MockTransport): fast, no network.

The background loops run for real, every 50 ms; a test waits for what they
read (``wait_until``) rather than sleeping.

Why one long file: every test drives the same server over the same fake
IaaSs; the browser's view is in test_wildfire_browser.py.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fake_iaas import KEY, FakeFederation, FakeIaas, robot
from fastapi.testclient import TestClient
from prometheus_client.parser import text_string_to_metric_families

from robocloud.errors import InvalidInput
from robocloud.wildfire import create_wildfire_app
from robocloud.wildfire.app import STATIC
from robocloud.wildfire.command import (
    add_wildfire_arguments,
    currency_label,
    forest_area,
    iaas_url,
    listen_address,
    page_url,
    wildfire_command,
)
from robocloud.wildfire.config import Forest, WildfireSettings
from robocloud.wildfire.fleet_view import capability_kinds
from waiting import wait_until

TASK = {"location": [100.0, 200.0], "actuating": {"grabber": 1}, "max_robots": 3,
        "max_cost": 10.0, "max_time": 60.0}


@pytest.fixture
def cloud_a() -> FakeIaas:
    return FakeIaas("cloud-a", [robot("a-0001", "cloud-a", caps=("grabber", "light")),
                                robot("a-0002", "cloud-a", "busy", ("kicker", "light"))])


@pytest.fixture
def cloud_b() -> FakeIaas:
    return FakeIaas("cloud-b", [robot("b-0001", "cloud-b", caps=("kicker", "sonar"))])


def settings(*clouds: FakeIaas, **changes: Any) -> WildfireSettings:
    return WildfireSettings(iaas=tuple(c.url for c in clouds), api_key=KEY, tick=0.05,
                            poll_timeout=0.5, timeout=1.0, **changes)


@pytest.fixture
def client(cloud_a: FakeIaas, cloud_b: FakeIaas) -> Iterator[TestClient]:
    cloud_a.listing = cloud_b.listing = [
        {"cloud": "cloud-a", "robots": 2, "idle": 1, "offline": 0},
        {"cloud": "cloud-b", "robots": 1, "idle": 1, "offline": 0}]
    # The federation view: cloud-a lists every robot; so does cloud-b.
    everyone = cloud_a.robots + cloud_b.robots
    cloud_a.robots = cloud_b.robots = everyone
    app = create_wildfire_app(settings(cloud_a, cloud_b),
                              transport=FakeFederation(cloud_a, cloud_b).transport())
    with TestClient(app) as test_client:
        wait_until(lambda: len(test_client.get("/api/robots").json()) == 3)
        yield test_client


# --- the page ---------------------------------------------------------------

def test_the_page_and_its_files_are_served_with_a_strict_policy(client: TestClient) -> None:
    page = client.get("/")
    assert page.status_code == 200
    assert page.headers["content-type"].startswith("text/html")
    policy = page.headers["content-security-policy"]
    assert "default-src 'self'" in policy and "script-src 'self'" in policy
    for asset in re.findall(r'(?:src|href)="(/static/[^"]+)"', page.text):
        answer = client.get(asset)
        assert answer.status_code == 200, asset
    script = client.get("/static/js/app.js", headers={"Accept-Encoding": "gzip"})
    assert script.headers["content-type"].startswith(("text/javascript", "application/javascript"))
    assert script.headers["content-encoding"] == "gzip"


def test_every_asset_is_local_no_cdn() -> None:
    files = [p for p in STATIC.rglob("*") if p.is_file()]
    assert {p.suffix for p in files} >= {".html", ".css", ".js", ".svg"}
    for path in files:
        text = path.read_text(encoding="utf-8")
        urls = set(re.findall(r"(?:https?:)?//[A-Za-z0-9.-]+\.[a-z]{2,}[^\s\"')]*", text))
        urls.discard("http://www.w3.org/2000/svg")  # the SVG namespace, not a download
        assert not urls, f"{path.name} refers to {urls}"
        assert "@import" not in text and "url(http" not in text
    scripts = re.findall(r'<script[^>]*src="([^"]+)"', (STATIC / "index.html").read_text())
    assert scripts == ["/static/js/app.js"]


def test_the_key_never_reaches_the_browser(client: TestClient, cloud_a: FakeIaas) -> None:
    cloud_a.add("x")
    answers = [client.get("/"), client.get("/static/js/api.js"), client.get("/api/robots"),
               client.get("/api/health"), client.get("/api/requests"),
               client.get("/api/config"), client.post("/api/requests/req-a0000/cancel")]
    for answer in answers:
        assert KEY not in answer.text
        assert KEY not in str(answer.headers)
    assert all(call.headers["authorization"] == f"Bearer {KEY}" for call in cloud_a.calls)


def test_an_unknown_path_is_a_sentence(client: TestClient) -> None:
    answer = client.get("/api/nothing")
    assert answer.status_code == 404
    assert answer.json() == {"detail": "there is no such path."}


# --- what the page shows -----------------------------------------------------------

def test_the_fleet_capabilities_clouds_and_config(client: TestClient) -> None:
    robots = {r["id"]: r for r in client.get("/api/robots").json()}
    assert set(robots) == {"a-0001", "a-0002", "b-0001"}
    assert robots["a-0001"] | {"heard": None} == {
        "id": "a-0001", "cloud": "cloud-a", "status": "idle", "x": 100, "y": 200, "battery": 80,
        "capabilities": ["grabber", "light"], "request": None, "phase": None,
        "progress": None, "heard": None}
    assert client.get("/api/robots").headers["cache-control"] == "no-store"
    assert client.get("/api/capabilities").json() == [
        {"name": "grabber", "kind": "actuating", "robots": 1, "idle": 1},
        {"name": "kicker", "kind": "actuating", "robots": 2, "idle": 1},
        {"name": "light", "kind": "sensing", "robots": 2, "idle": 1},
        {"name": "sonar", "kind": "sensing", "robots": 1, "idle": 1},
    ]
    clouds = wait_until(
        lambda: [c for c in client.get("/api/clouds").json() if c["status"] == "up"]
    )
    assert [(c["name"], c["robots"], c["idle"], c["iaas"]) for c in clouds] == [
        ("cloud-a", 2, 1, "http://cloud-a.test"), ("cloud-b", 1, 1, "http://cloud-b.test")]
    assert len({c["colour"] for c in clouds}) == 2
    config = client.get("/api/config").json()
    assert config["forest"] == {"x0": 0.0, "y0": 0.0, "x1": 2000.0, "y1": 2000.0}
    assert config["currency"] == "credits" and config["time_scale"] == 10.0
    health = client.get("/api/health").json()
    assert [(e["cloud"], e["ok"]) for e in health["endpoints"]] == [
        ("cloud-a", True), ("cloud-b", True)]


def test_the_iaas_may_say_the_kind_of_each_capability() -> None:
    robot_ = {"capabilities": ["grabber", "water"], "capability_kinds": {"water": "actuating"}}
    assert capability_kinds(robot_) == {"grabber": "actuating", "water": "actuating"}
    modelled = {"capabilities": {"hose": {"kind": "actuating", "time": 1.0, "cost": 1.0}}}
    assert capability_kinds(modelled) == {"hose": "actuating"}
    assert capability_kinds({"capabilities": ["x" * 65, 3, "ok"]}) == {"ok": "sensing"}
    assert capability_kinds({"capabilities": "grabber"}) == {}


def read_events(client: TestClient, count: int) -> list[tuple[str, dict[str, Any]]]:
    """The first ``count`` events of the live stream, gunzipped as a browser would."""
    events: list[tuple[str, dict[str, Any]]] = []
    with client.stream("GET", "/api/live", headers={"Accept-Encoding": "gzip"}) as stream:
        assert stream.headers["content-encoding"] == "gzip"
        assert stream.headers["content-type"].startswith("text/event-stream")
        inflate = zlib.decompressobj(31)
        text = ""
        for chunk in stream.iter_raw():
            text += inflate.decompress(chunk).decode()
            while "\n\n" in text:
                block, text = text.split("\n\n", 1)
                fields = dict(line.split(": ", 1) for line in block.splitlines() if ": " in line)
                if "event" in fields:
                    events.append((fields["event"], json.loads(fields["data"])))
            if len(events) >= count:
                break
    return events


def test_the_live_stream_is_a_snapshot_then_deltas_gzipped(client: TestClient,
                                                           cloud_a: FakeIaas) -> None:
    events = read_events(client, 6)
    (first, snapshot), *deltas = events
    assert first == "snapshot"
    assert snapshot["robots"]["columns"][:3] == ["id", "cloud", "status"]
    assert snapshot["config"]["currency"] == "credits"
    assert snapshot["config"]["silent_after"] == 5.0
    assert {name for name, _ in deltas} == {"delta"}
    # Applied as the page applies them, they give the fleet; once it is all
    # there, a delta is little more than the time.
    robots = {row[0] for row in snapshot["robots"]["rows"]}
    for _, delta in deltas:
        robots |= {row[0] for row in delta.get("robots", {}).get("add", [])}
    assert robots == {"a-0001", "a-0002", "b-0001"}
    assert set(deltas[-1][1]) <= {"now", "clouds", "capabilities", "endpoints", "config"}


def test_the_fleet_is_read_page_after_page(cloud_a: FakeIaas) -> None:
    cloud_a.robots = [robot(f"a-{i:04d}", "cloud-a") for i in range(5)]
    cloud_a.robots_page = 2
    app = create_wildfire_app(settings(cloud_a), transport=FakeFederation(cloud_a).transport())
    with TestClient(app) as client:
        robots = wait_until(lambda: len(got := client.get("/api/robots").json()) == 5 and got)
    assert sorted(r["id"] for r in robots) == [r["id"] for r in cloud_a.robots]
    pages = [c for c in cloud_a.calls if c.url.path == "/v1/robots"][:3]
    assert [c.url.params.get("cursor") for c in pages] == [None, "2", "4"]
    assert pages[0].url.params["limit"] == "10000"


def test_metrics_count_pages_streams_sends_and_upstream_errors(
        client: TestClient, cloud_a: FakeIaas) -> None:
    def scrape() -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
        answer = client.get("/metrics")
        assert answer.status_code == 200 and answer.headers["content-type"].startswith(
            "text/plain")
        return {(s.name, tuple(sorted(s.labels.items()))): s.value
                for family in text_string_to_metric_families(answer.text)
                for s in family.samples}

    before = scrape()
    assert before[("wildfire_sends_total", (("outcome", "accepted"),))] == 0
    client.get("/")
    read_events(client, 1)
    assert client.post("/api/requests", json=TASK).status_code == 202
    assert client.post("/api/requests", json={**TASK, "location": [-1e6, 0]}).status_code == 422
    cloud_a.down = True
    wait_until(lambda: scrape()[("wildfire_upstream_errors_total", (("iaas", cloud_a.url),))] > 0)
    cloud_a.down = False
    after = scrape()
    assert after[("wildfire_page_loads_total", ())] == 1
    assert after[("wildfire_live_connections_total", ())] == 1
    assert after[("wildfire_live_sent_bytes_total", ())] > 0
    assert after[("wildfire_sends_total", (("outcome", "accepted"),))] == 1
    assert after[("wildfire_sends_total", (("outcome", "refused"),))] == 1
    assert "/metrics" not in client.get("/openapi.json").json()["paths"]


# --- sending -------------------------------------------------------------------------

def test_a_request_is_sent_as_given_to_the_first_iaas(client: TestClient, cloud_a: FakeIaas
                                                      ) -> None:
    task = {**TASK, "label": "ridge"}
    answer = client.post("/api/requests", json=task, headers={"Idempotency-Key": "k-1"})
    assert answer.status_code == 202
    body = answer.json()
    assert body["held_by"] == "cloud-a" and body["label"] == "ridge"
    [sent] = [c for c in cloud_a.calls if c.method == "POST"]
    assert sent.url.path == "/v1/requests"
    assert json.loads(sent.content) == task
    assert sent.headers["idempotency-key"] == "k-1"
    # The same key again is the same request.
    again = client.post("/api/requests", json=task, headers={"Idempotency-Key": "k-1"})
    assert again.json()["id"] == body["id"]
    assert len(cloud_a.requests) == 1


def test_a_send_without_an_answer_is_unknown_and_its_retries_stay_with_that_iaas(
        client: TestClient, cloud_a: FakeIaas, cloud_b: FakeIaas) -> None:
    # Its sends alone go unanswered: its health still answers, so it stays first.
    cloud_a.hang_sends = True
    answer = client.post("/api/requests", json=TASK, headers={"Idempotency-Key": "k-2"})
    assert answer.status_code == 504
    assert answer.json() == {"detail": "the IaaS at http://cloud-a.test did not answer in time.",
                             "delivery": "unknown"}
    # cloud-a is down now and cloud-b answers, but the key may be at cloud-a: it waits for it.
    cloud_a.hang_sends, cloud_a.down = False, True
    wait_until(lambda: client.get("/api/health").json()["endpoints"][0]["ok"] is False)
    again = client.post("/api/requests", json=TASK, headers={"Idempotency-Key": "k-2"})
    assert again.status_code == 502
    assert again.json()["delivery"] == "none"
    assert not cloud_b.requests
    cloud_a.down = False
    found = client.post("/api/requests", json=TASK, headers={"Idempotency-Key": "k-2"})
    assert found.status_code == 202 and found.json()["held_by"] == "cloud-a"
    assert len(cloud_a.requests) == 1 and not cloud_b.requests


def test_a_send_refused_before_it_left_goes_to_the_next_iaas(
        client: TestClient, cloud_a: FakeIaas, cloud_b: FakeIaas) -> None:
    cloud_a.down = True
    answer = client.post("/api/requests", json=TASK, headers={"Idempotency-Key": "k-3"})
    assert answer.status_code == 202
    assert answer.json()["held_by"] == "cloud-b"
    assert not cloud_a.requests and len(cloud_b.requests) == 1
    # Found later at cloud-b, by id, whichever IaaS is asked first.
    request_id = answer.json()["id"]
    assert client.get(f"/api/requests/{request_id}").json()["held_by"] == "cloud-b"


BUSY = "this cloud is busy: 8 requests are waiting for their robots, the oldest for 0.61 s " \
       "(over 0.5 s); try again after Retry-After seconds."


def busy(fake: FakeIaas) -> None:
    """``fake`` refuses new requests as a busy IaaS does: 503, Retry-After, X-Robocloud-Busy."""
    import httpx

    fake.answer_only = "POST"
    fake.answer = lambda _: httpx.Response(
        503, json={"detail": BUSY}, headers={"Retry-After": "1", "X-Robocloud-Busy": "1"})


def test_a_busy_iaas_passes_the_send_to_the_next(
        client: TestClient, cloud_a: FakeIaas, cloud_b: FakeIaas) -> None:
    busy(cloud_a)
    answer = client.post("/api/requests", json=TASK, headers={"Idempotency-Key": "k-9"})
    assert answer.status_code == 202, answer.text
    assert answer.json()["held_by"] == "cloud-b"
    assert not cloud_a.requests and len(cloud_b.requests) == 1
    # Busy is not down: cloud-a is still healthy, and the key went to cloud-b alone.
    assert client.get("/api/health").json()["endpoints"][0]["ok"] is True
    again = client.post("/api/requests", json=TASK, headers={"Idempotency-Key": "k-9"})
    assert again.json()["id"] == answer.json()["id"]


def test_when_every_iaas_is_busy_the_page_is_told_nothing_was_sent(
        client: TestClient, cloud_a: FakeIaas, cloud_b: FakeIaas) -> None:
    busy(cloud_a)
    busy(cloud_b)
    answer = client.post("/api/requests", json=TASK, headers={"Idempotency-Key": "k-10"})
    assert answer.status_code == 503
    assert answer.json() == {"detail": BUSY, "delivery": "none"}
    assert not cloud_a.requests and not cloud_b.requests


def test_a_busy_answer_to_a_key_that_may_be_there_stays_unknown(
        client: TestClient, cloud_a: FakeIaas, cloud_b: FakeIaas) -> None:
    cloud_a.hang_sends = True  # the first send may have reached cloud-a
    first = client.post("/api/requests", json=TASK, headers={"Idempotency-Key": "k-11"})
    assert first.status_code == 504
    assert first.json()["delivery"] == "unknown"
    cloud_a.hang_sends = False
    busy(cloud_a)
    # cloud-a refuses before reading the key: the request may be there, so no other IaaS.
    again = client.post("/api/requests", json=TASK, headers={"Idempotency-Key": "k-11"})
    assert again.status_code == 503
    assert again.json() == {"detail": BUSY, "delivery": "unknown"}
    assert not cloud_b.requests


def test_an_iaas_failing_inside_may_hold_the_request(client: TestClient,
                                                     cloud_a: FakeIaas) -> None:
    import httpx

    # Its health stays good: the send goes to it, not to cloud-b.
    cloud_a.answer_only = "POST"
    cloud_a.answer = lambda _: httpx.Response(
        500, json={"detail": "the IaaS hit an internal error; it is logged."})
    answer = client.post("/api/requests", json=TASK, headers={"Idempotency-Key": "k-4"})
    assert answer.status_code == 500
    assert answer.json()["delivery"] == "unknown"


def test_a_fire_outside_the_forest_never_reaches_an_iaas(client: TestClient,
                                                         cloud_a: FakeIaas) -> None:
    answer = client.post("/api/requests", json={**TASK, "location": [2500, -100]})
    assert answer.status_code == 422
    assert answer.json() == {"detail": "location: the fire at (2,500, -100) is outside the "
                                       "forest, which spans x from 0 to 2,000 m and y from 0 "
                                       "to 2,000 m."}
    assert not [c for c in cloud_a.calls if c.method == "POST"]


def test_a_capability_no_robot_has_is_refused_by_name(client: TestClient,
                                                      cloud_a: FakeIaas) -> None:
    answer = client.post("/api/requests", json={**TASK, "sensing": {"laser": 1}})
    assert answer.status_code == 422
    assert answer.json()["detail"] == (
        "sensing.laser: no robot of the federation has the capability 'laser'; the fleet has "
        "grabber, kicker, light, sonar.")
    assert not [c for c in cloud_a.calls if c.method == "POST"]


@pytest.mark.parametrize(("body", "headers", "status", "detail"), [
    (b"x" * (64 * 1024 + 1), {}, 413, "the body is over 65536 bytes, the most accepted."),
    (b"", {}, 422, "the request body is missing: send a JSON task."),
    (b"{nope", {}, 422, "the body is not JSON: send a task as a JSON object."),
    (b"{}", {"Idempotency-Key": "k" * 201}, 422,
     "the Idempotency-Key header must be 1 to 200 printable characters without spaces."),
    (b"{}", {"Idempotency-Key": "two words"}, 422,
     "the Idempotency-Key header must be 1 to 200 printable characters without spaces."),
])
def test_bad_sends_are_refused_with_a_sentence(client: TestClient, cloud_a: FakeIaas,
                                               body: bytes, headers: dict[str, str],
                                               status: int, detail: str) -> None:
    answer = client.post("/api/requests", content=body,
                         headers={"Content-Type": "application/json", **headers})
    assert (answer.status_code, answer.json()) == (status, {"detail": detail})
    assert not [c for c in cloud_a.calls if c.method == "POST"]


@pytest.mark.parametrize(("status", "detail"), [
    (422, "max_cost: input should be greater than or equal to 0."),
    (401, "the API key is not valid."),
    (409, "req-a0000 is completed; a finished request cannot be canceled."),
])
def test_iaas_errors_come_back_with_their_status_and_sentence(
        client: TestClient, cloud_a: FakeIaas, status: int, detail: str) -> None:
    import httpx

    cloud_a.answer = lambda _: httpx.Response(status, json={"detail": detail})
    answer = client.post("/api/requests", json=TASK)
    assert answer.status_code == status
    assert answer.json() == {"detail": detail}


# --- finding and listing requests -------------------------------------------------------

def test_a_request_is_found_at_the_iaas_that_holds_it(client: TestClient, cloud_a: FakeIaas,
                                                      cloud_b: FakeIaas) -> None:
    record = cloud_b.add("at b")
    answer = client.get(f"/api/requests/{record['id']}")
    assert answer.status_code == 200 and answer.json()["held_by"] == "cloud-b"
    asked_a = len(cloud_a.calls)
    assert client.post(f"/api/requests/{record['id']}/cancel").json()["state"] == "canceled"
    assert not [c for c in cloud_a.calls[asked_a:] if record["id"] in c.url.path]
    missing = client.get("/api/requests/req-nothing")
    assert missing.status_code == 404 and "req-nothing" in missing.json()["detail"]


@pytest.mark.parametrize("request_id", ["..", "a.b", "%2E%2E", "x" * 200, "-x"])
def test_an_id_that_could_leave_its_route_never_reaches_an_iaas(
        client: TestClient, cloud_a: FakeIaas, request_id: str) -> None:
    for answer in (client.get(f"/api/requests/{request_id}"),
                   client.post(f"/api/requests/{request_id}/cancel")):
        assert answer.status_code == 404
        assert answer.json()["detail"]
    assert not [c for c in cloud_a.calls if c.url.path.startswith("/v1/requests/")]


def test_one_list_over_every_iaas_pages_beyond_fifty(client: TestClient, cloud_a: FakeIaas,
                                                     cloud_b: FakeIaas) -> None:
    for i in range(40):
        (cloud_a if i % 3 else cloud_b).add(f"r{i}", state="rejected" if i % 2 else "completed")
    every = sorted([*cloud_a.requests.values(), *cloud_b.requests.values()],
                   key=lambda r: (r["created_at"], r["id"]), reverse=True)
    seen: list[str] = []
    cursor = None
    pages = 0
    while True:
        params = {"limit": "15", **({"before": cursor} if cursor else {})}
        page = client.get("/api/requests", params=params).json()
        assert page["missing"] == []
        seen += [item["id"] for item in page["items"]]
        pages += 1
        cursor = page["next"]
        if not cursor:
            break
    assert seen == [r["id"] for r in every], "newest first over both, nothing twice"
    assert pages == 3
    rejected = client.get("/api/requests", params={"state": "rejected", "limit": "200"}).json()
    assert {i["state"] for i in rejected["items"]} == {"rejected"}
    assert len(rejected["items"]) == 20
    item = rejected["items"][0]
    assert set(item) >= {"id", "label", "state", "created_at", "cloud", "robots", "rev"}


def test_the_list_says_which_iaas_is_missing(client: TestClient, cloud_a: FakeIaas,
                                             cloud_b: FakeIaas) -> None:
    cloud_b.add("still here")
    cloud_a.down = True
    page = client.get("/api/requests").json()
    assert [i["label"] for i in page["items"]] == ["still here"]
    assert page["missing"] == [
        "the requests held by cloud-a (http://cloud-a.test) are not shown: the IaaS at "
        "http://cloud-a.test cannot be reached (Connection refused)."]


@pytest.mark.parametrize(("params", "detail"), [
    ({"before": "0:req-x,0:req-y"}, "before: this cursor was not given by this server; "
                                    "start again from the first page."),
    ({"before": "7:req-x"}, "before: this cursor was not given by this server; "
                            "start again from the first page."),
    ({"state": "burning"}, "state must be one of received, selecting, dispatched, underway, "
                           "completed, rejected, canceled, failed; 'burning' is not a state."),
    ({"limit": "0"}, "limit must be a whole number from 1 to 200."),
    ({"limit": "many"}, "limit must be a whole number from 1 to 200."),
])
def test_a_bad_list_query_is_a_sentence(client: TestClient, params: dict[str, str],
                                        detail: str) -> None:
    answer = client.get("/api/requests", params=params)
    assert (answer.status_code, answer.json()) == (422, {"detail": detail})


def test_no_iaas_answering_is_a_sentence(cloud_a: FakeIaas) -> None:
    cloud_a.down = True
    app = create_wildfire_app(settings(cloud_a), transport=FakeFederation(cloud_a).transport())
    with TestClient(app) as client:
        health = client.get("/api/health")
        assert health.status_code == 502
        assert health.json()["detail"] == ("no IaaS answers: http://cloud-a.test: the IaaS at "
                                           "http://cloud-a.test cannot be reached "
                                           "(Connection refused).")
        answer = client.post("/api/requests", json=TASK, headers={"Idempotency-Key": "k"})
        assert answer.status_code == 502 and answer.json()["delivery"] == "none"


# --- the command ------------------------------------------------------------

def test_the_command_line() -> None:
    import argparse

    parser = argparse.ArgumentParser()
    add_wildfire_arguments(parser)
    args = parser.parse_args(["--iaas", "http://127.0.0.1:8101/", "--iaas",
                              "http://127.0.0.1:8102", "--api-key", "k"])
    assert args.iaas == ["http://127.0.0.1:8101", "http://127.0.0.1:8102"]
    assert args.listen == ("127.0.0.1", 8000)
    assert args.forest == Forest(0, 0, 2000, 2000) and args.currency == "credits"
    assert args.silent_after == 5.0 and args.tick == 1.0
    args = parser.parse_args(["--iaas", "http://x:1", "--forest", "-500, 0, 1500,3000",
                              "--currency", "EUR", "--silent-after", "2.5", "--tick", "0.5"])
    assert args.forest == Forest(-500, 0, 1500, 3000) and args.currency == "EUR"
    assert args.silent_after == 2.5 and args.tick == 0.5
    assert listen_address("[::1]:9000") == ("::1", 9000)
    assert page_url("::1", 9000) == "http://[::1]:9000/"
    for bad in ("8000", "host:0", "host:x"):
        with pytest.raises(argparse.ArgumentTypeError):
            listen_address(bad)
    for bad in ("127.0.0.1:8101", "ftp://x", "http://"):
        with pytest.raises(argparse.ArgumentTypeError):
            iaas_url(bad)
    for bad in ("1,2,3", "0,0,0,10", "a,b,c,d", "0,0,1e9,1e9", "nan,0,1,1"):
        with pytest.raises(argparse.ArgumentTypeError):
            forest_area(bad)
    for bad in ("", "   ", "x" * 13, "a\nb"):
        with pytest.raises(argparse.ArgumentTypeError):
            currency_label(bad)


@pytest.mark.parametrize("flag", ["--tick", "--silent-after"])
@pytest.mark.parametrize("value", ["0", "nan", "-1"])
def test_the_periods_must_be_positive(flag: str, value: str) -> None:
    import argparse

    parser = argparse.ArgumentParser()
    add_wildfire_arguments(parser)
    args = parser.parse_args(["--iaas", "http://127.0.0.1:1", "--api-key", "k", flag, value])
    with pytest.raises(InvalidInput, match=f"^{flag} must be positive"):
        wildfire_command(args)


def test_the_module_runs_as_a_command() -> None:
    done = subprocess.run([sys.executable, "-m", "robocloud.wildfire.command", "--help"],
                          capture_output=True, text=True, timeout=60,
                          cwd=Path(__file__).parent)
    assert done.returncode == 0
    for flag in ("--iaas URL", "--listen HOST:PORT", "--forest X0,Y0,X1,Y1", "--currency LABEL"):
        assert flag in done.stdout
    done = subprocess.run([sys.executable, "-m", "robocloud.wildfire.command", "--iaas",
                           "http://127.0.0.1:1", "--timeout", "0"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert done.stderr.strip() == "robocloud: --timeout must be positive."
    done = subprocess.run([sys.executable, "-m", "robocloud.wildfire.command", "--iaas",
                           "http://127.0.0.1:1", "--iaas", "http://127.0.0.1:1/"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert done.stderr.strip() == "robocloud: an --iaas URL is given twice."
    done = subprocess.run([sys.executable, "-m", "robocloud.wildfire.command", "--iaas",
                           "http://127.0.0.1:1", "--forest", "1,2"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert "'1,2' is not X0,Y0,X1,Y1" in done.stderr
    # Without a key every call to the IaaS would be refused while the page looked fine.
    env = {k: v for k, v in os.environ.items() if k != "ROBOCLOUD_WILDFIRE_API_KEY"}
    done = subprocess.run([sys.executable, "-m", "robocloud.wildfire.command", "--iaas",
                           "http://127.0.0.1:1"], capture_output=True, text=True, timeout=60,
                          env=env)
    assert done.returncode == 2
    assert done.stderr.strip() == (
        "robocloud: no API key for the IaaS: set ROBOCLOUD_WILDFIRE_API_KEY "
        "(or pass --api-key) to a key the IaaS accepts.")


def test_an_answer_too_large_or_not_json_is_a_sentence(
        client: TestClient, cloud_a: FakeIaas, cloud_b: FakeIaas,
        monkeypatch: pytest.MonkeyPatch) -> None:
    import httpx

    from robocloud.wildfire import iaas_client

    cloud_b.down = True  # every send goes to cloud-a
    monkeypatch.setattr(iaas_client, "MAX_ANSWER_BYTES", 1000)
    cloud_a.answer = lambda _: httpx.Response(202, content=b"[" + b"1," * 1000 + b"1]")
    answer = client.post("/api/requests", json=TASK)
    assert (answer.status_code, answer.json()) == (502, {
        "detail": "the IaaS at http://cloud-a.test gave no usable answer: its answer is over "
                  "1000 bytes.", "delivery": "unknown"})
    cloud_a.answer = lambda _: httpx.Response(202, text="<html>a proxy page</html>")
    assert client.post("/api/requests", json=TASK).json()["detail"].endswith(
        "its answer is not JSON.")
    cloud_a.answer = lambda _: httpx.Response(500, text="<html>oops</html>")
    assert client.post("/api/requests", json=TASK).json() == {
        "detail": "the IaaS answered 500 Internal Server Error without a reason.",
        "delivery": "unknown"}


def test_a_lying_fleet_is_cut_to_what_the_page_can_show(cloud_a: FakeIaas) -> None:
    cloud_a.robots = [robot("x" * 65, "cloud-a"), robot("a-0001", "c" * 65),
                      robot("a-0002", "cloud-a")]
    cloud_a.listing = [{"cloud": f"cloud-{i}"} for i in range(100)]
    app = create_wildfire_app(settings(cloud_a), transport=FakeFederation(cloud_a).transport())
    with TestClient(app) as client:
        wait_until(lambda: client.get("/api/robots").json())
        assert [r["id"] for r in client.get("/api/robots").json()] == ["a-0002"]
        assert len(wait_until(lambda: client.get("/api/clouds").json())) <= 64
