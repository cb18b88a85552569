"""Requests and their history, the same on every store."""

from __future__ import annotations

import threading
from datetime import UTC
from typing import Any

import pytest
from storage_testing import TASK, Backend, new_in

from robocloud.domain import ACTIVE_STATES, FINAL_STATES, REQUEST_STATES, can_move
from robocloud.errors import Conflict, InvalidInput, NotFound
from robocloud.storage import RequestStore, StateChange


def test_create_and_get(store: RequestStore) -> None:
    record, created = store.create_request("wildfire", TASK, label="fire 1")
    assert created
    assert record.id.startswith("req-") and len(record.id) == 16
    assert record.id[4:].isalnum() and record.id == record.id.lower()
    assert (record.application, record.label, record.task) == ("wildfire", "fire 1", TASK)
    assert (record.state, record.reason, record.selection, record.idempotency_key) == (
        "received",
        None,
        None,
        None,
    )
    assert record.created_at.tzinfo is UTC and record.created_at == record.updated_at
    assert record.history == (StateChange("received", record.created_at, None, "state"),)
    assert store.get(record.id) == record
    assert store.get(record.id, application="wildfire") == record
    assert store.get(record.id, application="someone-else") is None
    assert store.get("req-nosuchrequest") is None


def test_records_do_not_share_json_with_the_store(store: RequestStore) -> None:
    location = [1, 2]
    record, _ = store.create_request("wildfire", {"location": location, "actuating": {"a": 1}})
    location.append(3)
    record.task["actuating"]["a"] = 99
    stored = store.get(record.id)
    assert stored is not None and stored.task == {"location": [1, 2], "actuating": {"a": 1}}


def test_ids_are_unique(store: RequestStore) -> None:
    ids = {store.create_request("wildfire", TASK)[0].id for _ in range(30)}
    assert len(ids) == 30


@pytest.mark.parametrize(
    ("arguments", "field"),
    [
        (("", TASK), "application"),
        (("wildfire", ["not", "an", "object"]), "task"),
        (("wildfire", {"x": float("nan")}), "task"),
        (("wildfire", {"x": object()}), "task"),
        (("wildfire", TASK, None, "k" * 256), "idempotency_key"),
        (("wildfire", TASK, 7), "label"),
    ],
)
def test_create_refuses_bad_input(
    store: RequestStore, arguments: tuple[Any, ...], field: str
) -> None:
    with pytest.raises(InvalidInput) as caught:
        store.create_request(*arguments)
    assert caught.value.field == field
    assert caught.value.message.endswith(".")
    assert store.list("wildfire") == ([], None)


def test_idempotency_key_returns_the_first_request(store: RequestStore) -> None:
    first, created = store.create_request("wildfire", TASK, idempotency_key="fire-17")
    store.transition(first.id, "selecting")
    again, created_again = store.create_request("wildfire", {"other": 1}, idempotency_key="fire-17")
    assert created and not created_again
    assert again.id == first.id and again.state == "selecting" and again.task == TASK
    other, created_other = store.create_request("patrol", TASK, idempotency_key="fire-17")
    assert created_other and other.id != first.id  # keys belong to one application
    assert store.create_request("wildfire", TASK)[0].idempotency_key is None
    assert len(store.list("wildfire")[0]) == 2


def test_idempotency_race_makes_one_request(backend: Backend) -> None:
    stores = backend.pair()
    threads = 12
    barrier = threading.Barrier(threads)
    results: list[tuple[str, bool]] = []
    errors: list[BaseException] = []

    def create(index: int) -> None:
        try:
            barrier.wait()
            record, created = stores[index % 2].create_request(
                "wildfire", TASK, idempotency_key="same-click"
            )
            results.append((record.id, created))
        except BaseException as error:  # reported below
            errors.append(error)

    workers = [threading.Thread(target=create, args=(i,)) for i in range(threads)]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join()
    assert errors == []
    assert len({request_id for request_id, _ in results}) == 1
    assert sum(created for _, created in results) == 1
    assert len(stores[0].list("wildfire")[0]) == 1


def test_list_is_newest_first_and_paginated(store: RequestStore) -> None:
    ids = [store.create_request("wildfire", TASK, label=str(i))[0].id for i in range(7)]
    store.create_request("patrol", TASK)
    newest_first = ids[::-1]

    page, cursor = store.list("wildfire", limit=3)
    assert [r.id for r in page] == newest_first[:3] and cursor == newest_first[2]
    page, cursor = store.list("wildfire", limit=3, before=cursor)
    assert [r.id for r in page] == newest_first[3:6] and cursor == newest_first[5]
    page, cursor = store.list("wildfire", limit=3, before=cursor)
    assert [r.id for r in page] == newest_first[6:] and cursor is None

    page, cursor = store.list("wildfire", limit=7)
    assert [r.id for r in page] == newest_first and cursor is None
    assert page[0].history == (StateChange("received", page[0].created_at),)
    assert store.list("nobody") == ([], None)


def test_list_filters_by_state(store: RequestStore) -> None:
    selecting = [new_in(store, "selecting") for _ in range(5)]
    new_in(store, "received")
    new_in(store, "canceled")
    page, cursor = store.list("wildfire", state="selecting", limit=2)
    assert [r.id for r in page] == selecting[::-1][:2]
    page, cursor = store.list("wildfire", state="selecting", limit=2, before=cursor)
    assert [r.id for r in page] == selecting[::-1][2:4]
    page, cursor = store.list("wildfire", state="selecting", limit=2, before=cursor)
    assert [r.id for r in page] == selecting[::-1][4:] and cursor is None
    assert [r.state for r in store.list("wildfire", state="canceled")[0]] == ["canceled"]
    assert store.list("wildfire", state="failed") == ([], None)


def test_list_refuses_bad_arguments(store: RequestStore) -> None:
    theirs, _ = store.create_request("patrol", TASK)
    with pytest.raises(InvalidInput, match="before=") as caught:
        store.list("wildfire", before=theirs.id)
    assert caught.value.field == "before"
    with pytest.raises(InvalidInput, match="before="):
        store.list("wildfire", before="req-nosuchrequest")
    for limit in (0, -1, 1001):
        with pytest.raises(InvalidInput, match="limit"):
            store.list("wildfire", limit=limit)
    with pytest.raises(InvalidInput, match="'done' is not a request state"):
        store.list("wildfire", state="done")


def test_every_move_is_allowed_or_refused_as_the_domain_says(store: RequestStore) -> None:
    for current in REQUEST_STATES:
        # Refused moves leave the request as it was, so one request per state serves them all.
        request_id = new_in(store, current)
        before = store.get(request_id)
        for new in REQUEST_STATES:
            if can_move(current, new):
                moved = store.transition(new_in(store, current), new)
                assert moved.state == new and moved.history[-1].state == new
            else:
                with pytest.raises(Conflict) as caught:
                    store.transition(request_id, new)
                assert request_id in caught.value.message and new in caught.value.message
        assert store.get(request_id) == before


def test_refusal_sentences(store: RequestStore) -> None:
    done = new_in(store, "completed")
    with pytest.raises(
        Conflict,
        match=rf"^Request {done} is already completed and cannot "
        r"become canceled\.$",
    ):
        store.transition(done, "canceled")
    waiting = new_in(store, "received")
    with pytest.raises(
        Conflict,
        match=rf"^Request {waiting} is received and cannot move to "
        r"underway\.$",
    ):
        store.transition(waiting, "underway")
    with pytest.raises(NotFound, match=r"^There is no request req-nosuchrequest\.$") as caught:
        store.transition("req-nosuchrequest", "selecting")
    assert caught.value.key == "req-nosuchrequest"
    with pytest.raises(InvalidInput, match="'finished' is not a request state"):
        store.transition(waiting, "finished")


def test_history_keeps_the_order_of_events(store: RequestStore) -> None:
    record, _ = store.create_request("wildfire", TASK)
    rid = record.id
    store.transition(rid, "selecting", detail="3 candidates")
    selection = {"coalition": ["a-0003", "b-0001"], "front": [[1.5, 200]], "elapsed_ms": 4.2}
    store.transition(rid, "dispatched", selection=selection)
    store.transition(rid, "underway")
    store.add_event(rid, "robot a-0003 failed; replaced by a-0017")
    store.transition(rid, "underway", detail="re-planned")
    final = store.transition(rid, "completed", reason="fire out")
    assert [(h.kind, h.state, h.detail) for h in final.history] == [
        ("state", "received", None),
        ("state", "selecting", "3 candidates"),
        ("state", "dispatched", None),
        ("state", "underway", None),
        ("event", "underway", "robot a-0003 failed; replaced by a-0017"),
        ("state", "underway", "re-planned"),
        ("state", "completed", None),
    ]
    times = [h.at for h in final.history]
    assert times == sorted(times) and len(set(times)) == len(times)
    assert all(t.tzinfo is UTC for t in times)
    assert final.updated_at == times[-1] and final.created_at == times[0]
    assert (final.state, final.reason, final.selection) == ("completed", "fire out", selection)
    assert store.get(rid) == final


def test_add_event_and_set_selection(store: RequestStore) -> None:
    rid = new_in(store, "completed")
    noted = store.add_event(rid, "robots back at base")  # allowed after the end too
    assert noted.state == "completed" and noted.history[-1].kind == "event"
    chosen = store.set_selection(rid, {"optimizer": "exact", "coalition": []})
    assert chosen.selection == {"optimizer": "exact", "coalition": []}
    assert chosen.history == noted.history and chosen.updated_at > noted.updated_at
    with pytest.raises(NotFound):
        store.add_event("req-nosuchrequest", "x")
    with pytest.raises(NotFound):
        store.set_selection("req-nosuchrequest", {})
    with pytest.raises(InvalidInput):
        store.set_selection(rid, {"bad": float("inf")})


def test_reason_and_selection_stay_unless_replaced(store: RequestStore) -> None:
    rid = new_in(store, "selecting")
    store.transition(rid, "dispatched", reason="best of 4", selection={"v": 1})
    record = store.transition(rid, "underway")
    assert (record.reason, record.selection) == ("best of 4", {"v": 1})


def test_active_lists_unfinished_requests_oldest_first(store: RequestStore) -> None:
    expected = []
    for state in REQUEST_STATES:
        request_id = new_in(store, state, application=f"app-{state}")
        if state in ACTIVE_STATES:
            expected.append(request_id)
    active = store.active()
    assert [r.id for r in active] == expected
    assert {r.state for r in active} == ACTIVE_STATES
    assert not {r.state for r in active} & FINAL_STATES


def test_a_request_is_found_by_its_idempotency_key_within_its_application(
    store: RequestStore,
) -> None:
    first, _ = store.create_request("wildfire", TASK, idempotency_key="fire-17")
    store.transition(first.id, "selecting")
    found = store.by_idempotency_key("wildfire", "fire-17")
    assert found is not None and found.id == first.id and found.state == "selecting"
    assert [h.state for h in found.history] == ["received", "selecting"]
    assert store.by_idempotency_key("patrol", "fire-17") is None  # another application's
    assert store.by_idempotency_key("wildfire", "fire-18") is None
