"""The wildfire server's mission routes: sent, checked, read, listed, canceled and followed.

The fake IaaSs answer in memory (httpx.MockTransport), as in
``test_wildfire_server.py``; the event stream is read from a fake served over
real HTTP on loopback (``served_iaas.py``), as a page follows it.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import pytest
from fake_iaas import KEY, FakeFederation, FakeIaas, robot
from fake_missions import advance
from fastapi.testclient import TestClient
from served_iaas import ServedIaas
from test_wildfire_server import settings

from robocloud.wildfire import create_wildfire_app
from robocloud.wildfire.config import WildfireSettings
from waiting import wait_until

MISSION = {
    "tasks": [{"id": "fire-1", "location": [300.0, 400.0], "actuating": {"grabber": 1}},
              {"id": "fire-2", "location": [900.0, 400.0], "actuating": {"grabber": 1},
               "sensing": {"light": 1}, "duration": 30.0}],
    "precedence": [["fire-1", "fire-2"]], "end": [100.0, 100.0], "priority": "time",
    "max_time": None, "min_battery": 0.0, "execution": "parallel", "label": "two fires",
}


def fleet(cloud: str) -> list[dict[str, Any]]:
    return [robot(f"{cloud[-1]}-0001", cloud, caps=("grabber", "light"), position=(100, 100)),
            robot(f"{cloud[-1]}-0002", cloud, caps=("grabber",), position=(1500, 300))]


@pytest.fixture
def clouds() -> tuple[FakeIaas, FakeIaas]:
    a, b = FakeIaas("cloud-a", fleet("cloud-a")), FakeIaas("cloud-b", fleet("cloud-b"))
    a.listing = b.listing = [{"cloud": c, "robots": 2, "idle": 2, "offline": 0}
                             for c in ("cloud-a", "cloud-b")]
    return a, b


@pytest.fixture
def client(clouds: tuple[FakeIaas, FakeIaas]) -> Iterator[TestClient]:
    app = create_wildfire_app(settings(*clouds), transport=FakeFederation(*clouds).transport())
    with TestClient(app) as test_client:
        wait_until(lambda: len(test_client.get("/api/robots").json()) == 2)
        yield test_client


def test_a_mission_is_sent_once_whatever_the_retries(
        client: TestClient, clouds: tuple[FakeIaas, FakeIaas]) -> None:
    a, b = clouds
    answer = client.post("/api/missions", json=MISSION, headers={"Idempotency-Key": "m-1"})
    assert answer.status_code == 202, answer.text
    mission = answer.json()
    assert mission["held_by"] == "cloud-a" and mission["label"] == "two fires"
    assert [t["id"] for t in mission["plan"]["tasks"]] == ["fire-1", "fire-2"]
    [sent] = [c for c in a.calls if c.method == "POST"]
    assert sent.url.path == "/v1/missions" and sent.headers["idempotency-key"] == "m-1"
    assert json.loads(sent.content) == MISSION
    again = client.post("/api/missions", json=MISSION, headers={"Idempotency-Key": "m-1"})
    assert again.json()["id"] == mission["id"]
    assert len(a.missions) == 1 and not b.missions
    # The IaaS's own refusal comes back as it is.
    other = client.post("/api/missions", json={**MISSION, "label": "x"},
                        headers={"Idempotency-Key": "m-1"})
    assert other.status_code == 422
    assert other.json() == {"detail": "the Idempotency-Key header was given before with "
                                      "another mission."}
    metrics = client.get("/metrics").text
    assert 'wildfire_mission_sends_total{outcome="accepted"} 2.0' in metrics
    assert 'wildfire_mission_sends_total{outcome="refused"} 1.0' in metrics
    assert 'wildfire_sends_total{outcome="accepted"} 0.0' in metrics


@pytest.mark.parametrize(("change", "status", "detail"), [
    ({"tasks": [MISSION["tasks"][0], {**MISSION["tasks"][1], "location": [2500, 10]}]}, 422,
     "tasks[1].location: the fire at (2,500, 10) is outside the forest, which spans x from 0 "
     "to 2,000 m and y from 0 to 2,000 m."),
    ({"end": [-5, 10]}, 422, "end: the end place at (-5, 10) is outside the forest, which "
                             "spans x from 0 to 2,000 m and y from 0 to 2,000 m."),
    ({"tasks": [{**MISSION["tasks"][0], "actuating": {"water": 2}}]}, 422,
     "tasks[0].actuating.water: no robot of the federation has the capability 'water'; the "
     "fleet has grabber, light."),
])
def test_a_mission_is_checked_as_a_task_is(client: TestClient, clouds: tuple[FakeIaas, FakeIaas],
                                           change: dict[str, Any], status: int,
                                           detail: str) -> None:
    answer = client.post("/api/missions", json={**MISSION, **change})
    assert (answer.status_code, answer.json()) == (status, {"detail": detail})
    assert not clouds[0].missions


@pytest.mark.parametrize(("body", "headers", "detail"), [
    (b"", {}, "the request body is missing: send a JSON mission."),
    (b"{nope", {}, "the body is not JSON: send a mission as a JSON object."),
    (json.dumps(MISSION).encode(), {"Idempotency-Key": "a b"}, None),
])
def test_bad_input_has_the_sentences_of_a_request(client: TestClient, body: bytes,
                                                  headers: dict[str, str],
                                                  detail: str | None) -> None:
    answer = client.post("/api/missions", content=body,
                         headers={"Content-Type": "application/json", **headers})
    assert answer.status_code == 422
    if detail is None:  # the key's rule, the one requests have
        same = client.post("/api/requests", content=body, headers={
            "Content-Type": "application/json", **headers})
        detail = same.json()["detail"]
        assert detail.startswith("the Idempotency-Key header must be")
    assert answer.json() == {"detail": detail}


def test_a_mission_is_read_listed_and_canceled_where_it_lives(
        client: TestClient, clouds: tuple[FakeIaas, FakeIaas]) -> None:
    a, b = clouds
    a.down = True  # the send goes to cloud-b
    wait_until(lambda: client.get("/api/health").json()["endpoints"][0]["ok"] is False)
    sent = client.post("/api/missions", json=MISSION, headers={"Idempotency-Key": "m-2"}).json()
    assert sent["held_by"] == "cloud-b"
    a.down = False
    wait_until(lambda: client.get("/api/health").json()["endpoints"][0]["ok"] is True)
    read = client.get(f"/api/missions/{sent['id']}").json()
    assert read["id"] == sent["id"] and read["held_by"] == "cloud-b"
    listed = client.get("/api/missions").json()
    assert [m["id"] for m in listed["items"]] == [sent["id"]]
    assert listed["missing"] == []
    canceled = client.delete(f"/api/missions/{sent['id']}")
    assert canceled.status_code == 200 and canceled.json()["state"] == "canceled"
    assert [c.method for c in b.calls if c.url.path == f"/v1/missions/{sent['id']}"][-1] == \
        "DELETE"
    assert not [c for c in a.calls if c.method == "DELETE"]
    missing = client.get("/api/missions/mis-nothing")
    assert missing.status_code == 404
    assert missing.json() == {"detail": "there is no mission 'mis-nothing'."}
    assert client.get("/api/missions/a..b").json() == {"detail": "there is no mission 'a..b'."}
    assert client.get("/api/missions?limit=x").json() == {
        "detail": "limit must be a whole number from 1 to 200."}


def test_the_events_of_a_mission_are_relayed_until_it_is_final() -> None:
    fake = FakeIaas("cloud-a", fleet("cloud-a"))
    served = ServedIaas(fake).start()
    try:
        app = create_wildfire_app(WildfireSettings(iaas=(served.url,), api_key=KEY, tick=0.2,
                                                   poll_timeout=1.0, timeout=2.0))
        with TestClient(app) as client:
            # A bound, not a claim: a loaded machine reads the first fleet late.
            wait_until(lambda: len(client.get("/api/robots").json()) == 2, timeout=30)
            mission = client.post("/api/missions", json=MISSION).json()
            seen: list[dict[str, Any]] = []
            with client.stream("GET", f"/api/missions/{mission['id']}/events") as stream:
                assert stream.headers["content-type"].startswith("text/event-stream")
                lines = stream.iter_lines()
                for line in lines:
                    if not line.startswith("data: "):
                        continue
                    seen.append(json.loads(line.removeprefix("data: ")))
                    if len(seen) == 1:
                        with fake.lock:
                            advance(fake.missions[mission["id"]], 35.0)
                        fake.changed()
                    elif len(seen) == 2:
                        with fake.lock:
                            advance(fake.missions[mission["id"]], 1e6)
                        fake.changed()
                # The IaaS closed the stream on the final mission: so did the server.
            assert [m["state"] for m in seen] == ["underway", "underway", "completed"]
            assert seen[1]["plan"]["tasks"][0]["state"] in ("travel", "waiting", "work")
            assert seen[2]["progress"] == 1.0
            wait_until(lambda: served.streams == 0, timeout=30)
            assert client.get("/api/missions/mis-none/events").json() == {
                "detail": "there is no mission 'mis-none'."}
    finally:
        served.stop()


def test_an_iaas_without_missions_lists_none_and_says_so(
        client: TestClient, clouds: tuple[FakeIaas, FakeIaas]) -> None:
    """An IaaS older than missions answers 404 for /v1/missions: the list is empty, not an error."""
    for fake in clouds:
        fake.offers_missions = False
    listed = client.get("/api/missions")
    assert listed.status_code == 200
    assert listed.json() == {"items": [], "next": None, "missing": [
        "cloud-a (http://cloud-a.test) does not offer missions (its IaaS has no /v1/missions).",
        "cloud-b (http://cloud-b.test) does not offer missions (its IaaS has no /v1/missions)."]}
