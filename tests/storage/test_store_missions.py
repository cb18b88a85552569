"""Missions in the store: the same rules on memory, SQLite and PostgreSQL."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from storage_testing import Backend

from robocloud.storage import MissionRow, SqlRequestStore


def row(n: int, state: str = "underway", key: str | None = None, app: str = "app") -> MissionRow:
    return MissionRow(
        id=f"mis-aaaaaaaaaaa{n}",
        application=app,
        idempotency_key=key,
        state=state,
        created_at=1000.0 + n,
        document={"id": f"mis-aaaaaaaaaaa{n}", "state": state, "history": [{"note": "é"}]},
    )


def test_a_mission_is_stored_updated_and_found_again_after_a_restart(backend: Backend) -> None:
    store = backend.open()
    assert store.save_mission(row(2, key="k")) == row(2, key="k")
    store.save_mission(row(2, state="completed", key="k"))
    _, again = backend.pair()  # another process on the same data (memory: the same store)
    again = again if backend.persistent else store
    found = again.mission("mis-aaaaaaaaaaa2")
    assert found is not None and found.state == "completed"
    assert found.document["state"] == "completed" and found.document["history"][0]["note"] == "é"
    assert again.mission("mis-aaaaaaaaaaa2", "other") is None
    assert again.mission_by_key("app", "k") == found
    assert again.unfinished_missions() == []


def test_a_key_used_again_gives_the_first_mission(backend: Backend) -> None:
    store = backend.open()
    first = store.save_mission(row(2, key="k"))
    assert store.save_mission(row(3, key="k")) == first
    assert store.mission("mis-aaaaaaaaaaa3") is None
    assert store.save_mission(row(3, key="k", app="other")).id == "mis-aaaaaaaaaaa3"


def test_missions_are_listed_newest_first_page_by_page(backend: Backend) -> None:
    store = backend.open()
    for n in range(2, 7):
        store.save_mission(row(n, state="completed" if n % 2 else "underway"))
    store.save_mission(row(7, app="other"))
    page, cursor = store.missions("app", None, 2, None)
    assert [r.id[-1] for r in page] == ["6", "5"] and cursor == page[-1].id
    page, cursor = store.missions("app", None, 2, cursor)
    assert [r.id[-1] for r in page] == ["4", "3"]
    page, cursor = store.missions("app", None, 2, cursor)
    assert [r.id[-1] for r in page] == ["2"] and cursor is None
    done, _ = store.missions("app", "completed", 10, None)
    assert [r.id[-1] for r in done] == ["5", "3"]
    assert {r.id[-1] for r in store.unfinished_missions()} == {"2", "4", "6", "7"}


def test_a_store_made_before_missions_gains_their_table(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'old.db'}"
    SqlRequestStore(url).close()
    with sqlite3.connect(tmp_path / "old.db") as old:  # as a store of the last release
        old.execute("DROP TABLE missions")
    store = SqlRequestStore(url)
    try:
        store.save_mission(row(2))
        assert store.mission("mis-aaaaaaaaaaa2") == row(2)
    finally:
        store.close()
