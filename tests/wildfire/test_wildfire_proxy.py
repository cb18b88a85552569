"""The wildfire server over a fake IaaS (httpx.MockTransport): fast, no network."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi.testclient import TestClient

from robocloud.wildfire import create_wildfire_app
from robocloud.wildfire.app import STATIC
from robocloud.wildfire.command import (
    add_wildfire_arguments,
    iaas_url,
    listen_address,
    page_url,
)
from robocloud.wildfire.fleet_view import capability_kinds, capability_offers, cloud_summaries

KEY = "s3cret-key"
IAAS = "http://iaas.test:8101"

ROBOTS: list[dict[str, Any]] = [
    {
        "id": "a-0001",
        "cloud": "cloud-a",
        "kind": "tribot",
        "position": [10.0, 20.0],
        "speed": 1.0,
        "battery": 90.0,
        "status": "idle",
        "capabilities": ["grabber", "light"],
        "request": None,
        "progress": None,
        "seen_ago": 0.1,
    },
    {
        "id": "a-0002",
        "cloud": "cloud-a",
        "kind": "base",
        "position": [30.0, 40.0],
        "speed": 1.0,
        "battery": 50.0,
        "status": "busy",
        "capabilities": ["kicker", "light"],
        "request": None,
        "progress": None,
        "seen_ago": 0.1,
    },
    {
        "id": "b-0001",
        "cloud": "cloud-b",
        "kind": "base",
        "position": [50.0, 60.0],
        "speed": 1.0,
        "battery": 80.0,
        "status": "idle",
        "capabilities": ["kicker", "sonar"],
        "request": None,
        "progress": None,
        "seen_ago": 0.2,
    },
]
REQUEST = {
    "id": "req-abc123",
    "label": None,
    "state": "received",
    "reason": None,
    "created_at": "2026-01-01T00:00:00Z",
    "updated_at": "2026-01-01T00:00:00Z",
    "task": {},
    "coalition": None,
    "time": None,
    "cost": None,
    "pareto": [],
    "optimizer": None,
    "selection_ms": None,
    "history": [],
}


class FakeIaas:
    """Answers like the IaaS; records what it was asked; ``answer`` overrides a route."""

    def __init__(self) -> None:
        self.calls: list[httpx.Request] = []
        self.answer: Callable[[httpx.Request], httpx.Response] | None = None

    def __call__(self, request: httpx.Request) -> httpx.Response:
        self.calls.append(request)
        if self.answer is not None:
            return self.answer(request)
        if request.headers.get("authorization") != f"Bearer {KEY}":
            return httpx.Response(401, json={"detail": "the API key is not valid."})
        path, method = request.url.path, request.method
        if path == "/healthz":
            return httpx.Response(
                200, json={"status": "ok", "cloud": "cloud-a", "robots": 3, "store": "sqlite"}
            )
        if path == "/v1/robots":
            return httpx.Response(200, json=ROBOTS)
        if path == "/v1/requests" and method == "GET":
            return httpx.Response(200, json={"items": [REQUEST], "next": None})
        if path == "/v1/requests" and method == "POST":
            return httpx.Response(202, json={**REQUEST, "task": json.loads(request.content)})
        if path == "/v1/requests/req-abc123":
            return httpx.Response(200, json=REQUEST)
        if path == "/v1/requests/req-abc123/cancel":
            return httpx.Response(
                409,
                json={"detail": "req-abc123 is completed; a finished request cannot be canceled."},
            )
        return httpx.Response(404, json={"detail": f"there is no request {path}."})


@pytest.fixture
def iaas() -> FakeIaas:
    return FakeIaas()


@pytest.fixture
def client(iaas: FakeIaas) -> Iterator[TestClient]:
    app = create_wildfire_app(IAAS, KEY, transport=httpx.MockTransport(iaas))
    with TestClient(app) as c:
        yield c


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
    assert (
        client.get("/static/js/app.js")
        .headers["content-type"]
        .startswith(("text/javascript", "application/javascript"))
    )


def test_every_asset_is_local_no_cdn() -> None:
    files = [p for p in STATIC.rglob("*") if p.is_file()]
    assert {p.suffix for p in files} >= {".html", ".css", ".js", ".svg"}
    for path in files:
        text = path.read_text(encoding="utf-8")
        urls = set(re.findall(r"(?:https?:)?//[A-Za-z0-9.-]+\.[a-z]{2,}[^\s\"')]*", text))
        urls.discard("http://www.w3.org/2000/svg")  # the SVG namespace, not a download
        assert not urls, f"{path.name} refers to {urls}"
    scripts = re.findall(r'<script[^>]*src="([^"]+)"', (STATIC / "index.html").read_text())
    assert scripts == ["/static/js/app.js"]


def test_the_key_never_reaches_the_browser(client: TestClient, iaas: FakeIaas) -> None:
    answers = [
        client.get("/"),
        client.get("/static/js/api.js"),
        client.get("/api/robots"),
        client.get("/api/health"),
        client.get("/api/requests"),
        client.post("/api/requests/req-abc123/cancel"),
    ]
    for answer in answers:
        assert KEY not in answer.text
        assert KEY not in str(answer.headers)
    assert all(call.headers["authorization"] == f"Bearer {KEY}" for call in iaas.calls)


def test_an_unknown_path_is_a_sentence(client: TestClient) -> None:
    answer = client.get("/api/nothing")
    assert answer.status_code == 404
    assert answer.json() == {"detail": "there is no such path."}


# --- the proxy --------------------------------------------------------------


def test_robots_of_the_whole_federation_pass_through(client: TestClient, iaas: FakeIaas) -> None:
    answer = client.get("/api/robots")
    assert answer.status_code == 200
    assert answer.json() == ROBOTS
    assert answer.headers["cache-control"] == "no-store"
    assert dict(iaas.calls[-1].url.params) == {"scope": "federation"}


def test_capabilities_are_derived_from_the_robots(client: TestClient) -> None:
    assert client.get("/api/capabilities").json() == [
        {"name": "grabber", "kind": "actuating", "robots": 1, "idle": 1},
        {"name": "kicker", "kind": "actuating", "robots": 2, "idle": 1},
        {"name": "light", "kind": "sensing", "robots": 2, "idle": 1},
        {"name": "sonar", "kind": "sensing", "robots": 1, "idle": 1},
    ]


def test_clouds_are_derived_from_the_robots(client: TestClient) -> None:
    assert client.get("/api/clouds").json() == [
        {"cloud": "cloud-a", "robots": 2, "idle": 1},
        {"cloud": "cloud-b", "robots": 1, "idle": 1},
    ]


def test_the_iaas_may_say_the_kind_of_each_capability() -> None:
    robot = {"capabilities": ["grabber", "water"], "capability_kinds": {"water": "actuating"}}
    assert capability_kinds(robot) == {"grabber": "actuating", "water": "actuating"}
    modelled = {"capabilities": {"hose": {"kind": "actuating", "time": 1.0, "cost": 1.0}}}
    assert capability_kinds(modelled) == {"hose": "actuating"}
    assert capability_offers([]) == [] and cloud_summaries([]) == []


def test_the_list_forwards_only_its_own_parameters(client: TestClient, iaas: FakeIaas) -> None:
    answer = client.get(
        "/api/requests", params={"state": "underway", "limit": "5", "before": "c1", "api_key": "x"}
    )
    assert answer.status_code == 200
    assert answer.json()["items"][0]["id"] == "req-abc123"
    sent = iaas.calls[-1].url
    assert dict(sent.params) == {"state": "underway", "limit": "5", "before": "c1"}


def test_a_request_is_sent_as_given(client: TestClient, iaas: FakeIaas) -> None:
    task = {
        "location": [1.0, 2.0],
        "actuating": {"grabber": 1},
        "max_robots": 3,
        "max_cost": 10.0,
        "max_time": 60.0,
        "label": "ridge",
    }
    answer = client.post("/api/requests", json=task, headers={"Idempotency-Key": "k-1"})
    assert answer.status_code == 202
    assert answer.json()["task"] == task
    sent = iaas.calls[-1]
    assert sent.method == "POST" and sent.url.path == "/v1/requests"
    assert json.loads(sent.content) == task
    assert sent.headers["idempotency-key"] == "k-1"
    assert sent.headers["content-type"] == "application/json"


def test_get_state_of_a_request(client: TestClient) -> None:
    assert client.get("/api/requests/req-abc123").json() == REQUEST


@pytest.mark.parametrize(
    ("status", "detail"),
    [
        (422, "max_cost: input should be greater than or equal to 0."),
        (401, "the API key is not valid."),
        (413, "the body is 70000 bytes; at most 65536 are accepted."),
    ],
)
def test_iaas_errors_come_back_with_their_status_and_sentence(
    client: TestClient, iaas: FakeIaas, status: int, detail: str
) -> None:
    iaas.answer = lambda _: httpx.Response(status, json={"detail": detail})
    answer = client.post("/api/requests", json={"location": [0, 0]})
    assert answer.status_code == status
    assert answer.json() == {"detail": detail}


def test_a_finished_request_cannot_be_canceled(client: TestClient) -> None:
    answer = client.post("/api/requests/req-abc123/cancel")
    assert answer.status_code == 409
    assert "cannot be canceled" in answer.json()["detail"]


def test_an_unknown_request_is_404(client: TestClient) -> None:
    answer = client.get("/api/requests/req-none")
    assert answer.status_code == 404
    assert answer.json()["detail"].startswith("there is no request")


@pytest.mark.parametrize("request_id", ["..", "a.b", "%2E%2E", "x" * 200, "-x"])
def test_an_id_that_could_leave_its_route_never_reaches_the_iaas(
    client: TestClient, iaas: FakeIaas, request_id: str
) -> None:
    for answer in (
        client.get(f"/api/requests/{request_id}"),
        client.post(f"/api/requests/{request_id}/cancel"),
    ):
        assert answer.status_code == 404
        assert answer.json()["detail"]
    assert not [c for c in iaas.calls if c.url.path.startswith("/v1/requests/")]


def test_an_unreachable_iaas_is_502_with_a_sentence(client: TestClient, iaas: FakeIaas) -> None:
    def refuse(request: httpx.Request) -> httpx.Response:
        raise httpx.ConnectError("Connection refused", request=request)

    iaas.answer = refuse
    answer = client.get("/api/robots")
    assert answer.status_code == 502
    assert answer.json() == {
        "detail": f"the IaaS at {IAAS} cannot be reached (Connection refused)."
    }


def test_a_silent_iaas_is_502_too(client: TestClient, iaas: FakeIaas) -> None:
    def hang(request: httpx.Request) -> httpx.Response:
        raise httpx.ReadTimeout("timed out", request=request)

    iaas.answer = hang
    answer = client.get("/api/requests/req-abc123")
    assert answer.status_code == 502
    assert "did not answer in time" in answer.json()["detail"]


def test_an_answer_that_is_not_json(client: TestClient, iaas: FakeIaas) -> None:
    iaas.answer = lambda _: httpx.Response(500, text="<html>oops</html>")
    answer = client.get("/api/robots")
    assert answer.status_code == 500
    assert answer.json() == {
        "detail": "the IaaS answered 500 Internal Server Error without a reason."
    }
    iaas.answer = lambda _: httpx.Response(200, text="<html>a proxy page</html>")
    answer = client.get("/api/robots")
    assert answer.status_code == 502
    assert "not JSON" in answer.json()["detail"]
    iaas.answer = lambda _: httpx.Response(200, json={"not": "a list"})
    assert client.get("/api/capabilities").status_code == 502


def test_bodies_are_bounded(client: TestClient, iaas: FakeIaas) -> None:
    answer = client.post(
        "/api/requests",
        content=b"x" * (64 * 1024 + 1),
        headers={"content-type": "application/json"},
    )
    assert answer.status_code == 413
    answer = client.post("/api/requests", content=b"")
    assert answer.status_code == 422
    assert answer.json() == {"detail": "the request body is missing: send a JSON task."}
    answer = client.post("/api/requests", json={}, headers={"Idempotency-Key": "k" * 201})
    assert answer.status_code == 422
    assert not [c for c in iaas.calls if c.method == "POST"]


def test_no_key_means_no_authorization_header(iaas: FakeIaas) -> None:
    app = create_wildfire_app(IAAS, None, transport=httpx.MockTransport(iaas))
    with TestClient(app) as client:
        answer = client.get("/api/robots")
    assert answer.status_code == 401
    assert answer.json() == {"detail": "the API key is not valid."}
    assert "authorization" not in iaas.calls[-1].headers


# --- the command ------------------------------------------------------------


def test_the_command_line() -> None:
    import argparse

    parser = argparse.ArgumentParser()
    add_wildfire_arguments(parser)
    args = parser.parse_args(["--iaas", "http://127.0.0.1:8101/", "--api-key", "k"])
    assert args.iaas == "http://127.0.0.1:8101"
    assert args.listen == ("127.0.0.1", 8000)
    assert listen_address("[::1]:9000") == ("::1", 9000)
    assert page_url("::1", 9000) == "http://[::1]:9000/"
    for bad in ("8000", "host:0", "host:x"):
        with pytest.raises(argparse.ArgumentTypeError):
            listen_address(bad)
    for bad in ("127.0.0.1:8101", "ftp://x", "http://"):
        with pytest.raises(argparse.ArgumentTypeError):
            iaas_url(bad)


def test_the_module_runs_as_a_command() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "robocloud.wildfire.command", "--help"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=Path(__file__).parent,
    )
    assert done.returncode == 0
    assert "--iaas URL" in done.stdout and "--listen HOST:PORT" in done.stdout
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "robocloud.wildfire.command",
            "--iaas",
            "http://127.0.0.1:1",
            "--timeout",
            "0",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2
    assert done.stderr.strip() == "robocloud wildfire: --timeout must be positive."
