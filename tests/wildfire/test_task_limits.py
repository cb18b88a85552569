"""The task's bounds the page's form checks: the IaaS's own, read from its OpenAPI document."""

from __future__ import annotations

import copy
from collections.abc import Iterator
from typing import Any

import pytest
from fake_iaas import KEY, FakeFederation, FakeIaas, robot
from fastapi.testclient import TestClient

from robocloud.domain.task import MAX_COST, MAX_COUNT, MAX_ROBOTS, MAX_TIME
from robocloud.fleet import MemoryRobotLink
from robocloud.iaas.app import create_app
from robocloud.iaas.config import Settings
from robocloud.storage import MemoryRequestStore
from robocloud.wildfire import create_wildfire_app
from robocloud.wildfire.config import WildfireSettings
from robocloud.wildfire.task_limits import task_limits
from waiting import wait_until


@pytest.fixture(scope="module")
def iaas_spec() -> Iterator[dict[str, Any]]:
    """The real IaaS's OpenAPI document, as ``robocloud iaas`` serves it."""
    app = create_app(Settings(cloud="cloud-a", selection_workers=0), store=MemoryRequestStore(),
                     link=MemoryRobotLink("cloud-a", []))
    with TestClient(app) as client:
        answer = client.get("/openapi.json")  # open: no key
        assert answer.status_code == 200
        yield answer.json()


def test_the_bounds_are_the_ones_the_iaas_checks(iaas_spec: dict[str, Any]) -> None:
    assert task_limits(iaas_spec) == {
        "count": {"min": 1, "max": MAX_COUNT},
        "max_robots": {"min": 1, "max": MAX_ROBOTS},
        "max_cost": {"min": 0, "max": MAX_COST},
        "max_time": {"min": 0, "max": MAX_TIME},
        "min_battery": {"min": 0, "max": 100},
        "label": {"max_length": 200},
    }


def _without(spec: dict[str, Any], *path: str) -> dict[str, Any]:
    changed = copy.deepcopy(spec)
    node = changed
    for part in path[:-1]:
        node = node[part]
    del node[path[-1]]
    return changed


@pytest.mark.parametrize("broken", [
    None, [], "openapi", {}, {"paths": []}, {"paths": {"/v1/requests": "post"}},
    {"paths": {"/v1/requests": {"post": {"requestBody": {"content": {
        "application/json": {"schema": {"$ref": "https://elsewhere.test/schema"}}}}}}}},
    {"paths": {"/v1/requests": {"post": {"requestBody": {"content": {
        "application/json": {"schema": {"$ref": "#/loop"}}}}}}}, "loop": {"$ref": "#/loop"}},
])
def test_a_document_without_a_task_schema_gives_no_bounds(broken: Any) -> None:
    assert task_limits(broken) is None


def test_a_bound_the_document_does_not_state_is_left_to_the_iaas(
        iaas_spec: dict[str, Any]) -> None:
    schemas = ("components", "schemas", "RequestCreate", "properties")
    spec = _without(iaas_spec, *schemas, "max_cost", "maximum")
    spec = _without(spec, *schemas, "label")
    limits = task_limits(spec)
    assert limits is not None
    assert limits["max_cost"] == {"min": 0}
    assert "label" not in limits
    assert limits["count"] == {"min": 1, "max": MAX_COUNT}


def _listings(iaas: FakeIaas) -> int:
    """How many times ``iaas`` was asked for its newest requests (once a tick)."""
    return sum(c.method == "GET" and c.url.path == "/v1/requests" for c in iaas.calls)


def test_the_server_hands_the_page_the_bounds_of_the_iaas_it_uses(
        iaas_spec: dict[str, Any]) -> None:
    # cloud-a serves no document; cloud-b serves one with its own bound on counts.
    cloud_a = FakeIaas("cloud-a", [robot("a-0001", "cloud-a")])
    cloud_b = FakeIaas("cloud-b", [])
    cloud_b.spec = copy.deepcopy(iaas_spec)
    counts = cloud_b.spec["components"]["schemas"]["RequestCreate"]["properties"]["actuating"]
    counts["additionalProperties"]["maximum"] = 7
    settings = WildfireSettings(iaas=(cloud_a.url, cloud_b.url), api_key=KEY, tick=0.05,
                                poll_timeout=0.5, timeout=1.0)
    app = create_wildfire_app(settings, transport=FakeFederation(cloud_a, cloud_b).transport())
    with TestClient(app) as client:
        limits = wait_until(lambda: client.get("/api/config").json()["limits"])
        assert limits["count"] == {"min": 1, "max": 7}
        assert limits["max_robots"] == {"min": 1, "max": MAX_ROBOTS}
        # Each tick reads an IaaS's bounds (while the page has none) before its
        # newest requests: three more reads of those from each IaaS are three
        # more ticks in which it could have been asked again.
        listed = {iaas: _listings(iaas) for iaas in (cloud_a, cloud_b)}
        wait_until(lambda: all(_listings(iaas) >= n + 3 for iaas, n in listed.items()))
    asked = [c for c in cloud_a.calls + cloud_b.calls if c.url.path == "/openapi.json"]
    assert sorted(c.url.host for c in asked) == ["cloud-a.test", "cloud-b.test"]
