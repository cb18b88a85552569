"""The HTTP API's contract at its edges: status codes, headers and the OpenAPI document.

Each case was a hole found by fuzzing (schemathesis) or by hand: a traceback
or a wrong status code. The store-dependent ones run on the in-memory store,
a SQLite file and the local PostgreSQL.
"""

from __future__ import annotations

import secrets
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from robocloud.domain import REQUEST_STATES, Robot
from robocloud.fleet import MemoryRobotLink
from robocloud.iaas.app import create_app
from robocloud.iaas.config import Settings
from robocloud.storage import MemoryRequestStore, RequestStore, SqlRequestStore, StoreUnavailable

A = {"Authorization": "Bearer key-a"}
TASK: dict[str, Any] = {
    "location": [0.0, 0.0],
    "actuating": {"grabber": 1},
    "max_robots": 2,
    "max_cost": 100.0,
    "max_time": 300.0,
}
ROBOT = Robot.model_validate(
    {
        "id": "a-0001",
        "cloud": "cloud-a",
        "position": [10.0, 0.0],
        "speed": 1.0,
        "battery": 90.0,
        "status": "idle",
        "travel_cost_per_m": 0.1,
        "capabilities": {"grabber": {"kind": "actuating", "time": 20.0, "cost": 3.0}},
    }
)


def client_for(store: RequestStore) -> TestClient:
    # Applications of their own: the PostgreSQL database is shared by the session's tests.
    apps = {"key-a": f"a-{secrets.token_hex(4)}", "key-b": f"b-{secrets.token_hex(4)}"}
    settings = Settings(cloud="cloud-a", api_keys=apps, selection_workers=0)
    return TestClient(create_app(settings, store=store, link=MemoryRobotLink("cloud-a", [ROBOT])))


@pytest.fixture(params=["memory", "sqlite", "postgresql"])
def any_store(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[RequestStore]:
    if request.param == "memory":
        yield MemoryRequestStore()
        return
    if request.param == "sqlite":
        url = f"sqlite:///{tmp_path / 'http.db'}"
    else:
        url = request.getfixturevalue("postgres_url")
    store = SqlRequestStore(url)
    yield store
    store.close()


@pytest.fixture
def client() -> Iterator[TestClient]:
    with client_for(MemoryRequestStore()) as c:
        yield c


def test_events_of_an_unknown_or_foreign_request_are_404_before_any_stream(
    any_store: RequestStore,
) -> None:
    with client_for(any_store) as client:
        unknown = client.get("/v1/requests/req-aaaaaaaaaaaa/events", headers=A)
        assert unknown.status_code == 404
        assert unknown.headers["content-type"] == "application/json"
        assert "req-aaaaaaaaaaaa" in unknown.json()["detail"]
        rid = client.post("/v1/requests", json=TASK, headers=A).json()["id"]
        foreign = client.get(
            f"/v1/requests/{rid}/events", headers={"Authorization": "Bearer key-b"}
        )
        assert foreign.status_code == 404
        # The store is untouched and the next request is served.
        assert client.get(f"/v1/requests/{rid}", headers=A).status_code == 200


@pytest.mark.parametrize(
    ("path", "code"),
    [
        ("/v1/requests/req-%00aaaaaaaaaa", 404),
        ("/v1/requests/req-%00aaaaaaaaaa/events", 404),
        ("/v1/requests?before=req-%00", 422),
    ],
)
def test_nul_in_an_id_is_a_clear_error_on_every_store(
    any_store: RequestStore, path: str, code: int
) -> None:
    with client_for(any_store) as client:
        answer = client.get(path, headers=A)
        assert answer.status_code == code, answer.text
        assert answer.json()["detail"].endswith(".")


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"label": "fire\x00 17"}, "label"),
        ({"actuating": {"grab\x00ber": 1}}, "actuating"),
        ({"location": [1e308, -1e308]}, "location[0]"),
        ({"max_cost": 1e300}, "max_cost"),
        ({"actuating": {"grabber": 5000}}, "actuating.grabber"),
    ],
)
def test_characters_and_numbers_a_store_cannot_take_are_422_naming_the_field(
    any_store: RequestStore, change: dict[str, Any], field: str
) -> None:
    with client_for(any_store) as client:
        answer = client.post("/v1/requests", json={**TASK, **change}, headers=A)
        assert answer.status_code == 422, answer.text
        assert answer.json()["detail"].startswith(field), answer.json()
        assert client.get("/v1/requests", headers=A).json()["items"] == []


def test_405_names_every_allowed_method(client: TestClient) -> None:
    answer = client.put("/v1/requests", headers=A)
    assert answer.status_code == 405
    assert answer.headers["allow"] == "GET, POST"
    answer = client.delete("/v1/requests/req-aaaaaaaaaaaa", headers=A)
    assert answer.status_code == 405 and answer.headers["allow"] == "GET"


def test_a_single_valued_query_parameter_given_twice_is_422_naming_it(
    client: TestClient,
) -> None:
    """FastAPI would keep the last value in silence (found by schemathesis, ST201)."""
    answer = client.get("/v1/robots?cloud=cloud-a&cloud=cloud-b", headers=A)
    assert answer.status_code == 422
    assert "'cloud' is given more than once" in answer.json()["detail"]
    answer = client.get("/v1/requests?limit=5&state=received&limit=7", headers=A)
    assert answer.status_code == 422 and "'limit'" in answer.json()["detail"]
    # A list parameter may repeat; the key is still checked first.
    assert client.get("/v1/robots?capability=grabber&capability=x", headers=A).status_code == 200
    assert client.get("/v1/robots?cloud=a&cloud=b").status_code == 401


def test_the_key_is_checked_before_the_body_is_read(client: TestClient) -> None:
    for headers in ({}, {"Authorization": "Bearer wrong"}):
        answer = client.post(
            "/v1/requests",
            content=b"{not json",
            headers={**headers, "Content-Type": "application/json"},
        )
        assert answer.status_code == 401
        assert answer.headers["www-authenticate"] == "Bearer"
    big = b"x" * 100_000
    assert client.post("/v1/requests", content=big).status_code == 401
    assert client.post("/v1/requests", content=big, headers=A).status_code == 413


def test_a_json_body_repeating_a_key_is_422_naming_it(client: TestClient) -> None:
    """Python's json and pydantic kept the last of a repeated key in silence (issue 25)."""
    import json

    body = json.dumps(TASK)[:-1] + ', "max_robots": 1, "max_robots": 5}'
    for content_type in ({"Content-Type": "application/json"}, {}):
        answer = client.post("/v1/requests", content=body, headers={**A, **content_type})
        assert answer.status_code == 422
        assert answer.json()["detail"] == (
            "max_robots: the key 'max_robots' is given more than once; give each key once."
        )
    nested = json.dumps(TASK).replace('{"grabber": 1}', '{"grabber": 1, "grabber": 2}')
    answer = client.post("/v1/requests", content=nested,
                         headers={**A, "Content-Type": "application/json"})
    assert answer.status_code == 422
    assert answer.json()["detail"].startswith("actuating.grabber: the key 'grabber'")
    # Every route's body, not only the task's.
    rid = client.post("/v1/requests", json=TASK, headers=A).json()["id"]
    cancel = client.post(f"/v1/requests/{rid}/cancel", content=b'{"a": 1, "a": 1}',
                         headers={**A, "Content-Type": "application/json"})
    assert cancel.status_code == 422 and "'a'" in cancel.json()["detail"]
    assert [r["id"] for r in client.get("/v1/requests", headers=A).json()["items"]] == [rid]
    assert client.get(f"/v1/requests/{rid}", headers=A).json()["state"] != "canceled"


def test_an_idempotency_key_reused_with_another_body_is_422_naming_the_header(
    client: TestClient,
) -> None:
    key = {"Idempotency-Key": "fire-17"}
    first = client.post("/v1/requests", json=TASK, headers={**A, **key})
    again = client.post("/v1/requests", json=TASK, headers={**A, **key})
    assert first.status_code == again.status_code == 202
    assert first.json()["id"] == again.json()["id"]
    other = client.post("/v1/requests", json={**TASK, "max_cost": 50.0}, headers={**A, **key})
    assert other.status_code == 422
    assert other.json()["detail"].startswith("Idempotency-Key 'fire-17' was already used")
    relabeled = client.post("/v1/requests", json={**TASK, "label": "x"}, headers={**A, **key})
    assert relabeled.status_code == 422
    assert len(client.get("/v1/requests", headers=A).json()["items"]) == 1


def test_an_idempotency_key_is_1_to_200_printable_characters_without_spaces(
    client: TestClient,
) -> None:
    """An empty key was ignored in silence and a key with spaces taken (found by hand)."""
    for key in ("", "fire 17", "fire\t17", "x" * 201):
        answer = client.post("/v1/requests", json=TASK, headers={**A, "Idempotency-Key": key})
        assert answer.status_code == 422, key
        assert answer.json()["detail"].startswith("header.idempotency-key"), answer.json()
    answer = client.post("/v1/requests", json=TASK, headers={**A, "Idempotency-Key": "fire 17"})
    assert "printable characters without spaces" in answer.json()["detail"]
    assert client.get("/v1/requests", headers=A).json()["items"] == []
    assert client.post(
        "/v1/requests", json=TASK, headers={**A, "Idempotency-Key": "x" * 200}
    ).status_code == 202


def test_a_body_that_is_no_json_task_is_told_what_to_send(client: TestClient) -> None:
    import json

    body = json.dumps(TASK)
    form = client.post("/v1/requests", content=body,
                       headers={**A, "Content-Type": "application/x-www-form-urlencoded"})
    assert form.status_code == 422
    assert form.json()["detail"] == (
        "the body is not JSON: send the task with Content-Type: application/json."
    )
    listed = client.post("/v1/requests", content="[1, 2]",
                         headers={**A, "Content-Type": "application/json"})
    assert listed.json()["detail"] == "the body must be a JSON object: a task."
    deep = client.post("/v1/requests", content="[" * 30_000 + "]" * 30_000,
                       headers={**A, "Content-Type": "application/json"})
    assert deep.status_code == 422 and "nested too deep" in deep.json()["detail"]
    # A pattern's refusal says what is allowed, not the regular expression.
    label = client.post("/v1/requests", json={**TASK, "label": "fire\x0117"}, headers=A)
    assert label.json()["detail"] == (
        "label must be text without control characters (tab and newline are allowed)."
    )
    assert client.get("/v1/requests", headers=A).json()["items"] == []


def test_a_task_naming_more_than_a_hundred_capabilities_is_422_at_post(
    client: TestClient,
) -> None:
    """1,001 names were taken (202), then failed the request inside with a traceback:
    the question to the other clouds carries at most 1,000 (found by hand)."""
    many = {f"g{i}": 1 for i in range(1001)}
    answer = client.post("/v1/requests", json={**TASK, "actuating": many}, headers=A)
    assert answer.status_code == 422
    assert answer.json()["detail"].startswith("actuating: dictionary should have at most 100")
    both = {**TASK, "sensing": {f"s{i}": 1 for i in range(60)},
            "actuating": {f"a{i}": 1 for i in range(60)}}
    answer = client.post("/v1/requests", json=both, headers=A)
    assert answer.status_code == 422
    assert "at most 100 capabilities, sensing and actuating together, not 120" in (
        answer.json()["detail"]
    )
    assert client.get("/v1/requests", headers=A).json()["items"] == []


class DownStore(MemoryRequestStore):
    """A store whose database has gone away."""

    down = False

    def _check(self) -> None:
        if self.down:
            raise StoreUnavailable("Cannot use the store at postgresql://db/x: connection refused.")

    def create_request(self, *args: Any, **kwargs: Any) -> Any:
        self._check()
        return super().create_request(*args, **kwargs)

    def list(self, *args: Any, **kwargs: Any) -> Any:
        self._check()
        return super().list(*args, **kwargs)


def test_a_store_outage_is_503_with_retry_after_and_loses_nothing() -> None:
    store = DownStore()
    with client_for(store) as client:
        rid = client.post("/v1/requests", json=TASK, headers=A).json()["id"]
        store.down = True
        answer = client.post("/v1/requests", json=TASK, headers=A)
        assert answer.status_code == 503
        assert int(answer.headers["retry-after"]) >= 1
        assert "connection refused" in answer.json()["detail"]
        assert client.get("/v1/requests", headers=A).status_code == 503
        store.down = False
        items = client.get("/v1/requests", headers=A).json()["items"]
        assert [r["id"] for r in items] == [rid]


def test_the_openapi_declares_the_scheme_the_enums_and_the_real_answers(
    client: TestClient,
) -> None:
    spec = client.get("/openapi.json").json()
    schemes = spec["components"]["securitySchemes"]
    assert schemes["HTTPBearer"] == {
        "type": "http",
        "scheme": "bearer",
        "description": "the application's API key",
    }
    paths = spec["paths"]
    for path, operations in paths.items():
        for method, operation in operations.items():
            if path.startswith("/v1/"):
                assert operation["security"] == [{"HTTPBearer": []}], (method, path)
                assert "401" in operation["responses"], (method, path)
    assert set(paths["/v1/requests"]["post"]["responses"]) == {"202", "401", "413", "422", "503"}
    assert set(paths["/v1/requests/{request_id}/cancel"]["post"]["responses"]) == {
        "200",
        "401",
        "404",
        "409",
        "503",
    }
    assert set(paths["/healthz"]["get"]["responses"]) == {"200"}
    schemas = spec["components"]["schemas"]
    assert schemas["RequestPublic"]["properties"]["state"]["enum"] == list(REQUEST_STATES)
    assert schemas["ErrorBody"]["properties"]["detail"]["type"] == "string"
    create = schemas["RequestCreate"]
    assert {"required": ["sensing"], "properties": {"sensing": {"minProperties": 1}}} in create[
        "anyOf"
    ]
    state_param = next(
        p for p in paths["/v1/requests"]["get"]["parameters"] if p["name"] == "state"
    )
    assert "received" in str(state_param["schema"])
