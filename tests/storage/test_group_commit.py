"""SQLite's group commit: writes that wait for the write lock are committed together.

The test holds the store's write lock while writers line up, then lets go:
the first writer to get the lock commits every waiting write in one
transaction, each in a savepoint. ``together`` hands in several calls at
once. Commits are counted by SQLAlchemy's ``commit`` event (reads commit
too: counts are taken before the test reads).
"""

from __future__ import annotations

import sqlite3
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import event
from sqlalchemy.exc import DBAPIError
from storage_testing import TASK, Backend

from robocloud.errors import Conflict, NotFound, RoboCloudError
from robocloud.storage import SqlRequestStore, StoreUnavailable


@pytest.fixture
def store(tmp_path: Path) -> Iterator[SqlRequestStore]:
    opened = SqlRequestStore(f"sqlite:///{tmp_path / 'store.db'}")
    yield opened
    opened.close()


def _commits(store: SqlRequestStore) -> list[int]:
    counted: list[int] = []
    event.listen(store._engine, "commit", lambda _conn: counted.append(1))
    return counted


def _lined_up(store: SqlRequestStore, calls: list[Callable[[], Any]]) -> list[Any]:
    """Run ``calls`` in threads, in this order, while the write lock is held; then let go.

    Each call's answer, or the error it raised.
    """
    answers: list[Any] = [None] * len(calls)

    def run(i: int) -> None:
        try:
            answers[i] = calls[i]()
        except Exception as error:
            answers[i] = error

    lock = store._db._write_lock
    assert lock is not None
    threads = [threading.Thread(target=run, args=(i,)) for i in range(len(calls))]
    with lock:
        for n, thread in enumerate(threads, start=1):
            thread.start()
            deadline = time.monotonic() + 10
            while len(store._db._waiting) < n:  # in line before the next one starts
                assert time.monotonic() < deadline, "a writer never lined up"
                time.sleep(0.001)
    for thread in threads:
        thread.join(10)
    return answers


def test_waiting_writes_are_committed_in_one_transaction(
    store: SqlRequestStore, tmp_path: Path
) -> None:
    ids = [store.create_request("wildfire", TASK)[0].id for _ in range(8)]
    commits = _commits(store)

    answers = _lined_up(
        store,
        [lambda rid=rid: store.transition(rid, "selecting", detail="lined up") for rid in ids],
    )

    assert len(commits) == 1
    assert [a.state for a in answers] == ["selecting"] * 8
    assert [[h.state for h in a.history] for a in answers] == [["received", "selecting"]] * 8
    reopened = SqlRequestStore(f"sqlite:///{tmp_path / 'store.db'}")
    assert [reopened.get(rid) for rid in ids] == answers
    reopened.close()


def test_writes_of_one_group_apply_in_the_order_they_came(store: SqlRequestStore) -> None:
    rid = store.create_request("wildfire", TASK)[0].id
    commits = _commits(store)

    first, second, third = _lined_up(
        store,
        [
            lambda: store.transition(rid, "selecting"),
            lambda: store.reserve(rid, ["a-1", "a-2"]),
            lambda: store.transition(rid, "dispatched", detail="2 robots"),
        ],
    )

    assert len(commits) == 1
    assert [h.state for h in first.history] == ["received", "selecting"]
    assert second == []
    assert [h.state for h in third.history] == ["received", "selecting", "dispatched"]
    assert store.reservations(rid) == {"a-1": rid, "a-2": rid}


def test_a_write_that_fails_in_a_group_fails_alone(store: SqlRequestStore) -> None:
    ids = [store.create_request("wildfire", TASK)[0].id for _ in range(4)]
    done = store.create_request("wildfire", TASK)[0].id
    store.transition(done, "canceled")
    commits = _commits(store)

    answers = _lined_up(
        store,
        [
            lambda: store.transition(ids[0], "selecting"),
            lambda: store.reserve(ids[1], ["a-1"]),
            # A final request holds no robot: this write fails, in the same
            # transaction as the two before it and the two after.
            lambda: store.reserve(done, ["a-2"]),
            lambda: store.transition(ids[2], "selecting"),
            lambda: store.add_event(ids[3], "a note"),
        ],
    )

    # Its savepoint was rolled back; the four others were committed together.
    assert len(commits) == 1
    assert isinstance(answers[2], RoboCloudError)
    assert "a-2" not in store.reservations()
    assert answers[0].state == answers[3].state == "selecting"
    assert answers[1] == []
    assert store.reservations(ids[1]) == {"a-1": ids[1]}
    assert [h.detail for h in answers[4].history] == [None, "a note"]
    assert [store.get(i) for i in (ids[0], ids[2], ids[3])] == [
        answers[0],
        answers[3],
        answers[4],
    ]
    assert store.get(done).state == "canceled"


def test_calls_handed_in_together_share_one_transaction(store: SqlRequestStore) -> None:
    ids = [store.create_request("wildfire", TASK)[0].id for _ in range(3)]
    commits = _commits(store)

    outcomes = store.together(
        [
            lambda: store.transition(ids[0], "selecting"),
            lambda: store.transition(ids[0], "completed"),  # not from selecting: Conflict
            lambda: store.create_request("wildfire", TASK, idempotency_key="k-1"),
            lambda: store.create_request("wildfire", TASK, idempotency_key="k-1"),
            lambda: store.reserve(ids[1], ["a-1"]),
            lambda: store.reserve(ids[2], ["a-1"]),
        ]
    )

    assert len(commits) == 1
    assert outcomes[0].get().state == "selecting"
    assert isinstance(outcomes[1].error, RoboCloudError)
    first, created = outcomes[2].get()
    assert created and outcomes[3].get() == (first, False)
    assert outcomes[4].get() == [] and outcomes[5].get() == ["a-1"]
    assert store.get(ids[0]) == outcomes[0].get()
    assert store.reservations() == {"a-1": ids[1]}


def test_a_write_the_database_refused_runs_again_alone(store: SqlRequestStore) -> None:
    ids = [store.create_request("wildfire", TASK)[0].id for _ in range(2)]
    commits = _commits(store)
    attempts: list[int] = []

    def refused_once() -> Any:
        attempts.append(1)
        record = store.transition(ids[1], "selecting")
        if len(attempts) == 1:  # written, then refused: its savepoint is rolled back
            raise DBAPIError.instance(
                None, None, sqlite3.OperationalError("disk I/O error"), sqlite3.Error
            )
        return record

    outcomes = store.together([lambda: store.transition(ids[0], "selecting"), refused_once])

    assert len(commits) == 2  # the group, then the refused write alone
    assert len(attempts) == 2
    assert [h.state for h in outcomes[1].get().history] == ["received", "selecting"]
    assert store.get(ids[1]) == outcomes[1].get()
    assert store.get(ids[0]) == outcomes[0].get()


def test_a_write_alone_needs_no_group(store: SqlRequestStore) -> None:
    rid = store.create_request("wildfire", TASK)[0].id
    commits = _commits(store)
    assert store.transition(rid, "selecting").state == "selecting"
    assert len(commits) == 1
    assert store._db._waiting == []


def test_a_group_that_cannot_begin_fails_every_write_at_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("robocloud.storage.engine.BUSY_TIMEOUT_S", 0.1)
    path = tmp_path / "store.db"
    store = SqlRequestStore(f"sqlite:///{path}")
    ids = [store.create_request("wildfire", TASK)[0].id for _ in range(5)]
    begins: list[int] = []
    transaction = store._db._transaction

    def counted(**how: Any) -> Any:
        begins.append(1)
        return transaction(**how)

    monkeypatch.setattr(store._db, "_transaction", counted)
    other = sqlite3.connect(path, isolation_level=None)
    other.execute("BEGIN IMMEDIATE")  # another process holds the write lock

    outcomes = store.together([lambda rid=rid: store.transition(rid, "selecting") for rid in ids])

    # One try for the group: five writes one by one would each wait out the timeout.
    assert len(begins) == 1
    assert all(isinstance(o.error, StoreUnavailable) for o in outcomes)
    assert "locked" in str(outcomes[0].error)
    other.execute("ROLLBACK")
    other.close()
    assert {store.get(rid).state for rid in ids} == {"received"}  # type: ignore[union-attr]
    assert store.transition(ids[0], "selecting").state == "selecting"
    store.close()


def test_together_answers_each_call_on_every_store(backend: Backend) -> None:
    store = backend.open()
    rid = store.create_request("wildfire", TASK)[0].id

    outcomes = store.together(
        [
            lambda: store.transition(rid, "selecting"),
            lambda: store.transition(rid, "completed"),  # not from selecting
            lambda: store.reserve(rid, ["a-1"]),
            lambda: store.add_event("req-aaaaaaaaaaaa", "no such request"),
            lambda: store.add_event(rid, "after the others"),
        ]
    )

    assert outcomes[0].get().state == "selecting"
    assert isinstance(outcomes[1].error, Conflict)
    assert outcomes[2].get() == []
    assert isinstance(outcomes[3].error, NotFound)
    last = outcomes[4].get()
    assert [(h.state, h.detail) for h in last.history] == [
        ("received", None),
        ("selecting", None),
        ("selecting", "after the others"),
    ]
    assert store.get(rid) == last
    assert store.reservations() == {"a-1": rid}


def test_writes_keep_one_connection_and_a_broken_one_is_replaced(store: SqlRequestStore) -> None:
    checkouts: list[int] = []
    event.listen(store._engine, "checkout", lambda *_: checkouts.append(1))
    ids = [store.create_request("app", TASK)[0].id for _ in range(5)]
    for rid in ids:
        store.transition(rid, "selecting")
    assert len(checkouts) <= 1  # the first write may open the kept connection

    kept = store._db._kept_writer
    assert kept is not None
    kept.connection.driver_connection.close()  # type: ignore[union-attr]
    with pytest.raises(StoreUnavailable, match="closed database"):
        store.transition(ids[0], "rejected", reason="no robot")
    assert store._db._kept_writer is None
    store.transition(ids[1], "rejected", reason="no robot")  # on a new connection
    states = {rid: store.get(rid).state for rid in ids}  # type: ignore[union-attr]
    assert states == {ids[0]: "selecting", ids[1]: "rejected",
                      **{rid: "selecting" for rid in ids[2:]}}
