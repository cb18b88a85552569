"""``GET /v1/robots`` in pages (filters, cursor, ETag, gzip) and ``GET /metrics``, over real HTTP.

One IaaS served by uvicorn on loopback, over the in-memory robot link and
store: the pages are walked as a client walks them (following ``Link``), and
``/metrics`` is scraped and parsed with prometheus_client's own parser while a
request lives.
"""

from __future__ import annotations

import gzip
import json
import socket
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import httpx
import pytest
import uvicorn
from prometheus_client.parser import text_string_to_metric_families
from pydantic import TypeAdapter

from robocloud.domain import Robot
from robocloud.errors import InvalidInput
from robocloud.fleet import MemoryRobotLink
from robocloud.iaas.app import create_app
from robocloud.iaas.config import Settings
from robocloud.iaas.models import RobotPublic
from robocloud.iaas.robot_list import (
    RobotFilter,
    decode_cursor,
    encode_cursor,
    matches,
    page_of,
    remote_rows,
)
from robocloud.storage import MemoryRequestStore, StoreUnavailable
from waiting import wait_until

KEY = "key-a"
A = {"Authorization": f"Bearer {KEY}"}
CAPS = {"light": "sensing", "grabber": "actuating", "kicker": "actuating"}
TASK: dict[str, Any] = {
    "location": [0.0, 0.0],
    "actuating": {"kicker": 1},
    "max_robots": 1,
    "max_cost": 1000.0,
    "max_time": 100000.0,
}
ROBOTS_ADAPTER = TypeAdapter(list[RobotPublic])


def robot(i: int, status: str, caps: tuple[str, ...]) -> Robot:
    return Robot.model_validate(
        {
            "id": f"a-{i:04d}",
            "cloud": "cloud-a",
            "position": [10.0 + i, 0.0],
            "speed": 1.0,
            "battery": 90.0,
            "status": status,
            "travel_cost_per_m": 0.1,
            "capabilities": {n: {"kind": CAPS[n], "time": 5.0, "cost": 1.0} for n in caps},
        }
    )


def fleet_of(n: int) -> list[Robot]:
    """Robots of every status and mixed capabilities, ids not in list order."""
    statuses = ("idle", "busy", "charging", "idle")
    caps = (("light",), ("grabber",), ("light", "grabber"), ("grabber", "kicker"))
    return [robot((i * 7) % 101, statuses[i % 4], caps[(i // 2) % 4]) for i in range(n)]


class FlakyStore(MemoryRequestStore):
    """The in-memory store, whose ``list`` can be made unavailable."""

    down = False

    def list(self, *args: Any, **kwargs: Any) -> Any:
        if self.down:
            raise StoreUnavailable("the store is down (a test).")
        return super().list(*args, **kwargs)


@dataclass
class Served:
    url: str
    link: MemoryRobotLink
    store: FlakyStore


@pytest.fixture(scope="module")
def served() -> Iterator[Served]:
    link = MemoryRobotLink("cloud-a", fleet_of(40), offline_after=3600.0)
    store = FlakyStore()
    app = create_app(
        Settings(cloud="cloud-a", api_keys={KEY: "app-a"}, selection_workers=0),
        store=store,
        link=link,
    )
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started:
        assert time.monotonic() < deadline and thread.is_alive(), "the IaaS did not start"
        time.sleep(0.02)
    yield Served(f"http://127.0.0.1:{port}", link, store)
    server.should_exit = True
    thread.join(10)


@pytest.fixture
def client(served: Served) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=served.url, headers=A, timeout=10) as c:
        yield c


def walk(client: httpx.Client, **params: Any) -> tuple[list[dict[str, Any]], int, int]:
    """Every robot of a listing, page after page: (robots, pages, X-Total-Count)."""
    robots: list[dict[str, Any]] = []
    answer = client.get("/v1/robots", params=params)
    pages = 1
    total = int(answer.headers["X-Total-Count"])
    while True:
        assert answer.status_code == 200, answer.text
        ROBOTS_ADAPTER.validate_json(answer.content)  # the documented shape, every page
        robots += answer.json()
        following = answer.links.get("next")
        if following is None:
            return robots, pages, total
        answer = client.get(following["url"])
        pages += 1


# -- pages ------------------------------------------------------------------------------


def test_a_walk_sees_every_robot_once_in_order(client: httpx.Client, served: Served) -> None:
    everyone = sorted(r.id for r in served.link.robots())
    robots, pages, total = walk(client, limit=7)
    ids = [r["id"] for r in robots]
    assert ids == everyone and total == len(everyone)
    assert pages == -(-len(everyone) // 7)
    # Without a limit, 40 robots are one page: no Link, as before pages existed.
    whole = client.get("/v1/robots")
    assert "link" not in whole.headers
    assert [r["id"] for r in whole.json()] == everyone


@pytest.mark.parametrize(
    ("params", "keeps"),
    [
        ({"status": "idle"}, lambda r: r.status == "idle"),
        ({"capability": "grabber"}, lambda r: "grabber" in r.capabilities),
        (
            {"capability": ["grabber", "light"], "status": "charging"},
            lambda r: {"grabber", "light"} <= set(r.capabilities) and r.status == "charging",
        ),
        ({"cloud": "cloud-a", "status": "busy"}, lambda r: r.status == "busy"),
        ({"cloud": "cloud-b"}, lambda r: False),
    ],
)
def test_filters_walk_the_matching_robots_once(
    client: httpx.Client, served: Served, params: dict[str, Any], keeps: Callable[[Robot], bool]
) -> None:
    wanted = sorted(r.id for r in served.link.robots() if keeps(r))
    robots, _, total = walk(client, limit=3, **params)
    assert [r["id"] for r in robots] == wanted
    assert total == len(wanted)
    for name, value in params.items():
        if name in ("status", "cloud"):
            assert all(r[name] == value for r in robots)


def test_robots_that_join_during_a_walk_leave_the_others_listed_once(
    client: httpx.Client, served: Served
) -> None:
    all_along = sorted(r.id for r in served.link.robots())
    answer = client.get("/v1/robots", params={"limit": 10})
    seen = [r["id"] for r in answer.json()]
    # One robot joins before the cursor (not listed by this walk), one after it.
    early, late = robot(0, "idle", ("light",)), robot(9000, "idle", ("light",))
    early = early.model_copy(update={"id": "a-0000-early"})
    served.link.put(early)
    served.link.put(late)
    while "next" in answer.links:
        answer = client.get(answer.links["next"]["url"])
        seen += [r["id"] for r in answer.json()]
    assert len(seen) == len(set(seen))
    assert sorted(set(seen) - {late.id}) == all_along and late.id in seen
    assert early.id not in seen and int(answer.headers["X-Total-Count"]) == len(all_along) + 2


def test_etag_answers_304_until_a_robot_changes(client: httpx.Client, served: Served) -> None:
    first = client.get("/v1/robots", params={"limit": 5})
    etag = first.headers["ETag"]
    assert etag.startswith('W/"')
    again = client.get("/v1/robots", params={"limit": 5}, headers={"If-None-Match": etag})
    assert again.status_code == 304 and again.content == b""
    assert again.headers["ETag"] == etag and again.headers["Link"] == first.headers["Link"]
    other = client.get("/v1/robots", params={"limit": 5}, headers={"If-None-Match": 'W/"x"'})
    assert other.status_code == 200 and other.headers["ETag"] == etag
    # A robot of the page reports a new battery: the page is new.
    changed = first.json()[0]["id"]
    state = served.link.state(changed)
    assert state is not None
    served.link.put(state.model_copy(update={"battery": 42.0}))
    try:
        after = client.get("/v1/robots", params={"limit": 5}, headers={"If-None-Match": etag})
        assert after.status_code == 200 and after.headers["ETag"] != etag
        assert after.json()[0]["battery"] == 42.0
    finally:
        served.link.put(state.model_copy(update={"battery": 90.0}))


def test_gzip_when_asked_only(client: httpx.Client) -> None:
    plain = client.get("/v1/robots", headers={"Accept-Encoding": "identity"})
    assert "content-encoding" not in plain.headers
    with client.stream("GET", "/v1/robots", headers={"Accept-Encoding": "gzip"}) as zipped:
        assert zipped.headers["content-encoding"] == "gzip"
        assert "Accept-Encoding" in zipped.headers["vary"]
        raw = b"".join(zipped.iter_raw())
    assert len(raw) < len(plain.content) / 4
    robots = json.loads(gzip.decompress(raw))
    assert [r["id"] for r in robots] == [r["id"] for r in plain.json()]


@pytest.mark.parametrize(
    ("params", "named"),
    [
        ({"limit": 0}, "limit"),
        ({"limit": 10001}, "limit"),
        ({"limit": "many"}, "limit"),
        ({"cursor": "not*a*cursor"}, "cursor"),
        ({"cursor": "bm90IGpzb24"}, "cursor"),  # base64 of "not json"
        ({"status": "flying"}, "status"),
        ({"capability": ""}, "capability"),
        ({"scope": "galaxy"}, "scope"),
    ],
)
def test_bad_parameters_are_422_with_a_sentence(
    client: httpx.Client, params: dict[str, Any], named: str
) -> None:
    answer = client.get("/v1/robots", params=params)
    assert answer.status_code == 422
    detail = answer.json()["detail"]
    assert named in detail and detail.endswith(".")


def test_the_cursor_is_opaque_and_round_trips() -> None:
    key = ("cloud-b", "robot ü/1")
    assert decode_cursor(encode_cursor(key)) == key
    with pytest.raises(InvalidInput, match="cursor"):
        decode_cursor(encode_cursor(key)[:-3])
    assert matches('W/"a", W/"b"', 'W/"b"') and matches("*", 'W/"c"')
    assert not matches('W/"a"', 'W/"b"') and not matches(None, 'W/"b"')


def test_other_clouds_robots_are_filtered_and_paged_with_this_clouds() -> None:
    def remote(i: int, cloud: str, status: str) -> dict[str, Any]:
        return {
            "id": f"{cloud}-{i}", "cloud": cloud, "position": [1, 2], "speed": 1,
            "battery": 50, "status": status, "kind": None, "request": None,
            "progress": {"phase": "travel", "progress": 0.5} if status == "busy" else None,
            "capabilities": {"light": {"kind": "sensing", "time": 1, "cost": 1}},
        }

    fleets = [
        [remote(i, "cloud-c", "idle") for i in range(3)] + [{"id": "broken"}],
        [remote(i, "cloud-b", ("idle", "busy")[i % 2]) for i in range(4)],
        [remote(9, "cloud-a", "idle")],  # this cloud's own: never twice
    ]
    rows = remote_rows(fleets, RobotFilter(status="idle"), "cloud-a")
    assert ROBOTS_ADAPTER.validate_python([r for _, r in rows])
    chosen, total, following = page_of(rows, None, 3)
    assert total == 5 and following == ("cloud-c", "cloud-c-0")
    assert [k for k, _ in chosen] == [("cloud-b", "cloud-b-0"), ("cloud-b", "cloud-b-2"),
                                      ("cloud-c", "cloud-c-0")]
    rest, _, end = page_of(rows, following, 3)
    assert [k[1] for k, _ in rest] == ["cloud-c-1", "cloud-c-2"] and end is None


# -- the OpenAPI ---------------------------------------------------------------------------


def test_the_openapi_documents_pages_and_leaves_metrics_out(client: httpx.Client) -> None:
    spec = client.get("/openapi.json").json()
    assert "/metrics" not in spec["paths"]
    operation = spec["paths"]["/v1/robots"]["get"]
    names = {p["name"] for p in operation["parameters"]}
    assert {"limit", "cursor", "status", "capability", "cloud", "if-none-match"} <= names
    assert "content" not in operation["responses"]["304"]
    assert {"ETag", "Link", "X-Total-Count"} <= set(operation["responses"]["200"]["headers"])
    assert set(operation["responses"]) == {"200", "304", "401", "422"}


# -- metrics --------------------------------------------------------------------------------


def scrape(client: httpx.Client) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    answer = client.get("/metrics")
    assert answer.status_code == 200
    assert answer.headers["content-type"].startswith("text/plain")
    samples = {}
    for family in text_string_to_metric_families(answer.text):
        for s in family.samples:
            samples[(s.name, tuple(sorted(s.labels.items())))] = s.value
    return samples


def value(samples: dict[tuple[str, tuple[tuple[str, str], ...]], float], name: str,
          **labels: str) -> float:
    return samples.get((name, tuple(sorted(labels.items()))), 0.0)


def test_metrics_need_an_api_key(served: Served) -> None:
    assert httpx.get(f"{served.url}/metrics").status_code == 401
    wrong = httpx.get(f"{served.url}/metrics", headers={"Authorization": "Bearer nope"})
    assert wrong.status_code == 401 and wrong.json()["detail"]


def test_metrics_move_with_a_request_s_life(client: httpx.Client, served: Served) -> None:
    before = scrape(client)
    kickers = [r.id for r in served.link.robots() if "kicker" in r.capabilities]
    assert value(before, "robocloud_robots", cloud="cloud-a", status="idle") > 0
    created = client.post("/v1/requests", json=TASK)
    assert created.status_code == 202
    rid = created.json()["id"]
    wait_until(
        lambda: client.get(f"/v1/requests/{rid}").json()["state"] in ("dispatched", "underway"),
        10.0,
    )
    during = scrape(client)

    def moved(name: str, **labels: str) -> float:
        return value(during, name, **labels) - value(before, name, **labels)

    for state in ("received", "selecting", "dispatched"):
        assert moved("robocloud_request_transitions_total", state=state) == 1
    assert moved("robocloud_selection_seconds_count") == 1
    assert moved("robocloud_selection_seconds_sum") > 0
    assert moved("robocloud_post_to_dispatched_seconds_count") == 1
    assert value(during, "robocloud_post_to_dispatched_seconds_bucket", le="+Inf") >= 1
    assert moved("robocloud_command_ack_seconds_count", command="assign") == 1
    assert value(during, "robocloud_requests_active", state="dispatched") + value(
        during, "robocloud_requests_active", state="underway"
    ) == 1
    # The chosen robot reports busy (the memory link answers at once).
    assert moved("robocloud_robots", cloud="cloud-a", status="busy") == 1
    assert any(r["id"] in kickers and r["request"] == rid
               for r in client.get("/v1/robots", params={"capability": "kicker"}).json())

    assert client.post(f"/v1/requests/{rid}/cancel").json()["state"] == "canceled"
    after = wait_until(lambda: (s := scrape(client)) and value(
        s, "robocloud_command_ack_seconds_count", command="stop") > value(
        before, "robocloud_command_ack_seconds_count", command="stop") and s, 10.0)
    assert value(after, "robocloud_requests_finished_total", outcome="canceled") - value(
        before, "robocloud_requests_finished_total", outcome="canceled") == 1
    wait_until(lambda: sum(value(scrape(client), "robocloud_requests_active", state=s)
                      for s in ("received", "selecting", "dispatched", "underway")) == 0, 10.0)


def test_store_errors_are_counted(client: httpx.Client, served: Served) -> None:
    before = value(scrape(client), "robocloud_store_errors_total", operation="list")
    served.store.down = True
    try:
        answer = client.get("/v1/requests")
    finally:
        served.store.down = False
    assert answer.status_code == 503 and answer.headers["Retry-After"]
    assert value(scrape(client), "robocloud_store_errors_total", operation="list") == before + 1


def test_the_event_stream_is_neither_gzipped_nor_held_back(client: httpx.Client) -> None:
    rid = client.post("/v1/requests", json=TASK).json()["id"]
    try:
        with client.stream(
            "GET", f"/v1/requests/{rid}/events", headers={"Accept-Encoding": "gzip"}
        ) as events:
            assert events.headers["content-type"].startswith("text/event-stream")
            assert "content-encoding" not in events.headers
            lines = events.iter_lines()
            first = next(line for line in lines if line.startswith("data:"))
            # The first event came while the request is still alive: not buffered to the end.
            assert json.loads(first.removeprefix("data:"))["id"] == rid
            assert client.get(f"/v1/requests/{rid}").json()["state"] not in (
                "completed", "canceled", "failed", "rejected")
    finally:
        client.post(f"/v1/requests/{rid}/cancel")
