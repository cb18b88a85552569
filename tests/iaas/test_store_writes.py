"""StoreWrites: the IaaS's store writes go in turns, several handed to the store together."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import event

from robocloud.errors import Conflict, NotFound
from robocloud.iaas.store_writes import StoreWrites
from robocloud.storage import MemoryRequestStore, RequestStore, SqlRequestStore, StoreUnavailable
from robocloud.storage.store import Outcome

TASK = {"location": [1.0, 2.0], "actuating": {"grabber": 1}, "max_robots": 2}


class Turns:
    """A store that records each ``together`` it is handed (and can refuse them all)."""

    def __init__(self, store: RequestStore) -> None:
        self.store = store
        self.turns: list[int] = []
        self.down = False

    def together(self, calls: Sequence[Callable[[], Any]]) -> list[Outcome]:
        self.turns.append(len(calls))
        if self.down:
            return [Outcome(error=StoreUnavailable("the store is down."))] * len(calls)
        return self.store.together(calls)


def test_writes_asked_together_go_in_few_turns_each_with_its_own_answer() -> None:
    store = MemoryRequestStore()
    ids = [store.create_request("wildfire", TASK)[0].id for _ in range(40)]
    turns = Turns(store)
    writes = StoreWrites(turns, ThreadPoolExecutor(1))  # type: ignore[arg-type]

    async def main() -> list[Any]:
        return await asyncio.gather(
            *(writes(store.transition, rid, "selecting") for rid in ids),
            writes(store.transition, ids[0], "completed"),  # not from selecting
            writes(store.add_event, "req-aaaaaaaaaaaa", "no such request"),
            return_exceptions=True,
        )

    answers = asyncio.run(main())

    assert [a.state for a in answers[:40]] == ["selecting"] * 40
    assert isinstance(answers[40], Conflict)
    assert isinstance(answers[41], NotFound)
    assert sum(turns.turns) == 42
    assert len(turns.turns) < 42  # the first turn took one, the next all that waited
    assert [store.get(rid) for rid in ids] == answers[:40]


def test_writes_are_made_in_the_order_they_were_asked_for() -> None:
    store = MemoryRequestStore()
    rid = store.create_request("wildfire", TASK)[0].id
    writes = StoreWrites(store, ThreadPoolExecutor(1))

    async def main() -> None:
        await asyncio.gather(
            writes(store.transition, rid, "selecting"),
            writes(store.add_event, rid, "one"),
            writes(store.add_event, rid, "two"),
            writes(store.transition, rid, "dispatched"),
        )

    asyncio.run(main())
    assert [(h.state, h.detail) for h in store.get(rid).history] == [  # type: ignore[union-attr]
        ("received", None),
        ("selecting", None),
        ("selecting", "one"),
        ("selecting", "two"),
        ("dispatched", None),
    ]


def test_a_store_that_is_down_fails_each_write_and_counts_it() -> None:
    store = MemoryRequestStore()
    rid = store.create_request("wildfire", TASK)[0].id
    turns = Turns(store)
    turns.down = True
    failed: list[str] = []
    writes = StoreWrites(
        turns,  # type: ignore[arg-type]
        ThreadPoolExecutor(1),
        lambda function: failed.append(function.__name__),
    )

    async def main() -> None:
        with pytest.raises(StoreUnavailable):
            await writes(store.transition, rid, "selecting")
        turns.down = False
        assert (await writes(store.transition, rid, "selecting")).state == "selecting"

    asyncio.run(main())
    assert failed == ["transition"]


def test_on_sqlite_a_turn_is_one_transaction(tmp_path: Path) -> None:
    store = SqlRequestStore(f"sqlite:///{tmp_path / 'store.db'}")
    ids = [store.create_request("wildfire", TASK)[0].id for _ in range(30)]
    commits: list[int] = []
    event.listen(store._engine, "commit", lambda _conn: commits.append(1))
    turns = Turns(store)
    writes = StoreWrites(turns, ThreadPoolExecutor(1))  # type: ignore[arg-type]

    async def main() -> list[Any]:
        return await asyncio.gather(*(writes(store.transition, rid, "selecting") for rid in ids))

    answers = asyncio.run(main())
    assert len(commits) == len(turns.turns) < 30
    assert [store.get(rid) for rid in ids] == answers
    store.close()


def test_several_takers_make_writes_side_by_side() -> None:
    store = MemoryRequestStore()
    ids = [store.create_request("wildfire", TASK)[0].id for _ in range(2)]

    class Slow(Turns):
        """A store whose turns wait for the test: a round trip to a database server."""

        def __init__(self, inner: RequestStore) -> None:
            super().__init__(inner)
            self.running = 0
            self.release = threading.Event()

        def together(self, calls: Sequence[Callable[[], Any]]) -> list[Outcome]:
            self.running += 1
            self.release.wait(10)
            self.running -= 1
            return super().together(calls)

    async def most_at_once(takers: int) -> int:
        slow = Slow(store)
        writes = StoreWrites(slow, ThreadPoolExecutor(4), takers=takers)  # type: ignore[arg-type]
        first = asyncio.ensure_future(writes(store.add_event, ids[0], "first"))
        while slow.running < 1:
            await asyncio.sleep(0.005)
        second = asyncio.ensure_future(writes(store.add_event, ids[1], "second"))
        deadline = time.monotonic() + 2
        while slow.running < 2 and time.monotonic() < deadline:
            await asyncio.sleep(0.005)
        most = slow.running
        slow.release.set()
        await asyncio.gather(first, second)
        return most

    assert asyncio.run(most_at_once(takers=1)) == 1  # the second waits for the next turn
    assert asyncio.run(most_at_once(takers=2)) == 2
    assert [len(store.get(rid).history) for rid in ids] == [3, 3]  # type: ignore[union-attr]
