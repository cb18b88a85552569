"""The IaaS serves the robot protocol: version, keys, timing, and the checked-in schemas."""

from __future__ import annotations

import json
from pathlib import Path

from fastapi.testclient import TestClient

from robocloud.fleet import MemoryRobotLink
from robocloud.iaas.app import create_app
from robocloud.iaas.config import Settings
from robocloud.storage import MemoryRequestStore

DOCS = Path(__file__).parents[2] / "docs" / "protocol"


def client(**settings: float) -> TestClient:
    app = create_app(
        Settings(cloud="cloud-a", api_keys={"k": "app"}, **settings),  # type: ignore[arg-type]
        store=MemoryRequestStore(),
        link=MemoryRobotLink("cloud-a"),
    )
    return TestClient(app)


def test_the_protocol_page_tells_the_version_keys_and_this_clouds_timing() -> None:
    with client(ack_timeout=1.5, offline_after=4.0) as http:
        answer = http.get("/protocol")  # no API key needed
    assert answer.status_code == 200
    info = answer.json()
    assert info["version"] == "1.2"
    assert info["keys"] == {
        "state": "robocloud/cloud-a/robots/<id>/state",
        "cmd": "robocloud/cloud-a/robots/<id>/cmd",
        "error": "robocloud/cloud-a/robots/<id>/error",
        "states": "robocloud/cloud-a/fleets/<gateway>/states",
    }
    assert info["timing"] == {
        "state_every": 1.0,
        "ack_timeout": 1.5,
        "offline_after": 4.0,
        "forget_after": 600.0,
    }
    assert set(info["schemas"]) == {"state", "command", "ack", "error", "states"}


def test_each_served_schema_is_the_checked_in_file() -> None:
    with client() as http:
        paths = http.get("/protocol").json()["schemas"]
        for name, path in paths.items():
            answer = http.get(path)
            assert answer.status_code == 200, path
            assert answer.headers["content-type"] == "application/schema+json"
            assert answer.json() == json.loads((DOCS / f"{name}.schema.json").read_text())


def test_the_protocol_routes_are_in_the_openapi_with_only_their_success() -> None:
    with client() as http:
        paths = http.get("/openapi.json").json()["paths"]
    assert set(paths["/protocol"]["get"]["responses"]) == {"200"}
    schema_answer = paths["/protocol/state.schema.json"]["get"]["responses"]
    assert set(schema_answer) == {"200"}
    # The media type it is served with, so a fuzzer finds no undocumented content type.
    assert set(schema_answer["200"]["content"]) == {"application/schema+json"}
