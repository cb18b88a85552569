"""What only the SQL store has: URLs, files, reopening, other processes."""

from __future__ import annotations

import multiprocessing
import sqlite3
import threading
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import Engine
from storage_testing import TASK, Backend, new_in

from robocloud.errors import InvalidInput, RoboCloudError
from robocloud.storage import (
    MemoryRequestStore,
    SqlRequestStore,
    StoreUnavailable,
    open_store,
)


def test_data_survives_close_and_reopen(sql_backend: Backend) -> None:
    store = sql_backend.open()
    record, _ = store.create_request("wildfire", TASK, label="fire", idempotency_key="k-1")
    store.transition(record.id, "selecting", detail="3 candidates")
    store.transition(record.id, "dispatched", selection={"coalition": ["a-1", "a-2"]})
    store.add_event(record.id, "robot a-1 is slow")
    store.reserve(record.id, ["a-1", "a-2"])
    store.reserve(record.id, ["a-3"], lease_seconds=600)
    done = new_in(store, "completed")
    before = (store.get(record.id), store.get(done), store.reservations(), store.active())
    store.close()

    reopened = sql_backend.open()
    after = (
        reopened.get(record.id),
        reopened.get(done),
        reopened.reservations(),
        reopened.active(),
    )
    assert after == before
    assert reopened.create_request("wildfire", {}, idempotency_key="k-1") == (before[0], False)
    assert reopened.list("wildfire")[0] == [before[1], before[0]]


def test_sqlite_file_is_in_wal_mode_with_utc_text_times(tmp_path: Path) -> None:
    path = tmp_path / "store.db"
    store = SqlRequestStore(f"sqlite:///{path}")
    record, _ = store.create_request("wildfire", TASK)
    with sqlite3.connect(path) as raw:
        assert raw.execute("PRAGMA journal_mode").fetchone() == ("wal",)
        created, task = raw.execute("SELECT created_at, task FROM requests").fetchone()
    assert created == record.created_at.strftime("%Y-%m-%d %H:%M:%S.%f")
    assert task.startswith('{"location":[400.0,310.0]')
    store.close()


def _reserve_in_another_process(
    url: str,
    wanted: dict[str, list[str]],
    barrier: Any,
    results: Any,
) -> None:
    """Reserve each request's robots from threads of this process and its own store."""
    store = SqlRequestStore(url)
    outcome: dict[str, list[str]] = {}
    barrier.wait()

    def reserve(request_id: str) -> None:
        outcome[request_id] = store.reserve(request_id, wanted[request_id])

    workers = [threading.Thread(target=reserve, args=(rid,)) for rid in wanted]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join()
    store.close()
    results.put(outcome)


def test_processes_sharing_a_database_cannot_double_book(sql_backend: Backend) -> None:
    assert sql_backend.url is not None
    store = sql_backend.open()
    fleet = [f"r-{i}" for i in range(12)]
    # Every request wants 4 consecutive robots of a ring: neighbours always overlap.
    wanted = {
        new_in(store, "selecting"): [fleet[(i + k) % 12] for k in range(4)] for i in range(12)
    }
    # A process must not inherit open database connections.
    store.close()
    # fork starts in milliseconds; spawn (elsewhere) in about a second.
    context: Any = multiprocessing.get_context(
        "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
    )
    count = 3
    barrier, results = context.Barrier(count), context.Queue()
    ids = list(wanted)
    processes = [
        context.Process(
            target=_reserve_in_another_process,
            args=(sql_backend.url, {rid: wanted[rid] for rid in ids[p::count]}, barrier, results),
        )
        for p in range(count)
    ]
    for process in processes:
        process.start()
    outcome = {rid: taken for _ in processes for rid, taken in results.get(timeout=60).items()}
    for process in processes:
        process.join(timeout=60)
        assert process.exitcode == 0

    winners = [rid for rid in ids if outcome[rid] == []]
    held: dict[str, str] = {}
    for rid in winners:
        for robot in wanted[rid]:
            assert robot not in held, f"{robot} reserved twice"
            held[robot] = rid
    for rid in ids:
        assert all(held[robot] != rid for robot in outcome[rid])
    assert winners and sql_backend.open().reservations() == held


@pytest.mark.parametrize(
    "url",
    [
        "mysql://user@host/robots",
        "postgresql+asyncpg://user@host/robots",
        "not a url",
        "",
        "sqlite://",
        "sqlite:///:memory:",
        "memory",
    ],
)
def test_unsupported_url_is_refused_with_a_sentence(url: str) -> None:
    with pytest.raises(InvalidInput) as caught:
        open_store(url)
    assert caught.value.message.startswith(f"store URL {url!r} is not a supported database URL")
    assert "use sqlite:///FILE or postgresql+psycopg://" in caught.value.message
    assert caught.value.field == "store_url"


def test_memory_url_opens_a_memory_store() -> None:
    assert isinstance(open_store("memory://"), MemoryRequestStore)


def test_sqlite_url_forms(tmp_path: Path) -> None:
    store = open_store(f"sqlite+pysqlite:///{tmp_path / 'a.db'}")
    assert isinstance(store, SqlRequestStore)
    store.close()


def test_missing_folder_is_a_sentence(tmp_path: Path) -> None:
    with pytest.raises(StoreUnavailable, match=r"the folder .*nowhere does not exist\.$"):
        open_store(f"sqlite:///{tmp_path / 'nowhere' / 'store.db'}")


def test_a_file_that_is_not_a_database_is_a_sentence(tmp_path: Path) -> None:
    path = tmp_path / "notes.db"
    path.write_bytes(b"these are not the tables you are looking for" * 100)
    with pytest.raises(StoreUnavailable, match=r"^Cannot use the store at sqlite.*notes\.db: "):
        open_store(f"sqlite:///{path}")


def test_unreachable_postgres_is_a_sentence_without_the_password() -> None:
    with pytest.raises(StoreUnavailable) as caught:
        open_store("postgresql://robocloud:s3cret@127.0.0.1:1/robots")
    message = caught.value.message
    assert message.startswith("Cannot use the store at postgresql+psycopg://robocloud:***@")
    assert "s3cret" not in message and "s3cret" not in (caught.value.url or "")
    assert isinstance(caught.value, RoboCloudError)


def test_missing_postgres_database_is_a_sentence(postgres_admin: Engine) -> None:
    url = postgres_admin.url.set(database="robocloud_no_such_database")
    with pytest.raises(StoreUnavailable, match=r"robocloud_no_such_database.*does not exist"):
        open_store(url.render_as_string(hide_password=False))
