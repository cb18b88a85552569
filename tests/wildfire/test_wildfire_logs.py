"""What the wildfire server logs (issue 26): at INFO what happened to requests and clouds,
each call to an IaaS only at DEBUG."""

from __future__ import annotations

import logging
from collections.abc import Iterator

import pytest
from fake_iaas import KEY, FakeFederation, FakeIaas, robot
from fastapi.testclient import TestClient

from robocloud.wildfire import create_wildfire_app
from robocloud.wildfire.command import quiet_iaas_calls
from robocloud.wildfire.config import WildfireSettings
from robocloud.wildfire.live import one_line
from waiting import wait_until

TASK = {"location": [100.0, 200.0], "actuating": {"grabber": 1}, "max_robots": 3,
        "max_cost": 10.0, "max_time": 60.0}


@pytest.fixture
def clouds() -> tuple[FakeIaas, FakeIaas]:
    a = FakeIaas("cloud-a", [robot("a-0001", "cloud-a")])
    b = FakeIaas("cloud-b", [robot("b-0001", "cloud-b", caps=("kicker",))])
    a.listing = b.listing = [{"cloud": "cloud-a", "robots": 1, "idle": 1, "offline": 0},
                             {"cloud": "cloud-b", "robots": 1, "idle": 1, "offline": 0}]
    a.robots = b.robots = a.robots + b.robots
    return a, b


@pytest.fixture
def restore_httpx() -> Iterator[None]:
    calls = logging.getLogger("httpx")
    level, filters = calls.level, list(calls.filters)
    yield
    calls.setLevel(level)
    calls.filters = filters


def serve(a: FakeIaas, b: FakeIaas) -> TestClient:
    settings = WildfireSettings(iaas=(a.url, b.url), api_key=KEY, tick=0.05, poll_timeout=0.5,
                                timeout=1.0)
    return TestClient(create_wildfire_app(settings, transport=FakeFederation(a, b).transport()))


def said(caplog: pytest.LogCaptureFixture, words: str, level: int = logging.INFO) -> bool:
    return any(words in r.getMessage() and r.levelno == level for r in caplog.records)


@pytest.mark.usefixtures("restore_httpx")
def test_info_says_what_happened_to_requests_and_clouds_not_each_call(
    clouds: tuple[FakeIaas, FakeIaas], caplog: pytest.LogCaptureFixture
) -> None:
    a, b = clouds
    quiet_iaas_calls(debug=False)
    caplog.set_level(logging.INFO)
    with serve(a, b) as client:
        wait_until(lambda: len(client.get("/api/robots").json()) == 2)
        rid = client.post("/api/requests", json=TASK).json()["id"]
        assert said(caplog, f"request {rid} sent to cloud-a (http://cloud-a.test): received.")
        refused = client.post("/api/requests", json={**TASK, "location": [-5.0, 0.0]})
        assert refused.status_code == 422
        assert said(caplog, "a request was refused (422): location:")
        client.post(f"/api/requests/{rid}/cancel")
        assert said(caplog, f"request {rid} canceled by the operator at cloud-a")
        assert said(caplog, f"Request {rid} is canceled.")  # a state change
        b.down = True
        wait_until(lambda: said(caplog, "cloud-b is down: its IaaS at http://cloud-b.test does not "
                                   "answer", logging.WARNING))
        b.down = False
        wait_until(lambda: said(caplog, "cloud-b is back"))
    # Each IaaS call (httpx's "HTTP Request: ..." lines) stayed out of INFO.
    assert a.calls and not [r for r in caplog.records if r.name.startswith("httpx")]


@pytest.mark.usefixtures("restore_httpx")
def test_debug_shows_each_call(clouds: tuple[FakeIaas, FakeIaas],
                               caplog: pytest.LogCaptureFixture) -> None:
    a, b = clouds
    quiet_iaas_calls(debug=True)
    caplog.set_level(logging.DEBUG)
    with serve(a, b) as client:
        wait_until(lambda: len(client.get("/api/robots").json()) == 2)
    calls = [r for r in caplog.records if r.getMessage().startswith("HTTP Request:")]
    assert calls and all(r.levelno == logging.DEBUG for r in calls)


def test_text_from_elsewhere_is_one_line() -> None:
    forged = "refused.\n2026-01-01 wildfire INFO robocloud: request req-x completed."
    assert "\n" not in one_line(forged) and one_line(forged).startswith("refused.\\x0a2026")
