"""What the storage tests share: backends, a fake clock, a task, requests in any state."""

from __future__ import annotations

import threading
from datetime import UTC, datetime, timedelta
from typing import Any

from robocloud.storage import MemoryRequestStore, RequestStore, SqlRequestStore
from robocloud.storage.rules import Clock

TASK: dict[str, Any] = {
    "location": [400.0, 310.0],
    "actuating": {"grabber": 2},
    "sensing": {"light": 1},
    "max_robots": 3,
    "max_cost": 500,
    "max_time": 600,
    "min_battery": 70,
    "priority": "time",
    "note": "feu de forêt ✓",
}

# One way to bring a new request to each state.
PATHS: dict[str, tuple[str, ...]] = {
    "received": (),
    "selecting": ("selecting",),
    "dispatched": ("selecting", "dispatched"),
    "underway": ("selecting", "dispatched", "underway"),
    "completed": ("selecting", "dispatched", "underway", "completed"),
    "rejected": ("selecting", "rejected"),
    "canceled": ("canceled",),
    "failed": ("selecting", "failed"),
}


def new_in(store: RequestStore, state: str, application: str = "wildfire") -> str:
    record, _ = store.create_request(application, TASK)
    for step in PATHS[state]:
        store.transition(record.id, step)
    return record.id


class FakeClock:
    """A clock that moves only when told to, for leases."""

    def __init__(self) -> None:
        self.now = datetime(2030, 1, 1, 12, 0, tzinfo=UTC)
        self._lock = threading.Lock()

    def __call__(self) -> datetime:
        with self._lock:
            return self.now

    def advance(self, seconds: float) -> None:
        with self._lock:
            self.now += timedelta(seconds=seconds)


class Backend:
    """Opens stores of one kind on one place; ``open`` twice = two processes sharing it."""

    def __init__(self, name: str, url: str | None) -> None:
        self.name = name
        self.url = url
        self._stores: list[RequestStore] = []
        self._memory: MemoryRequestStore | None = None

    @property
    def persistent(self) -> bool:
        return self.url is not None

    def open(self, clock: Clock | None = None) -> RequestStore:
        store: RequestStore
        if self.url is None:
            store = MemoryRequestStore(clock)
        else:
            store = SqlRequestStore(self.url, clock=clock)
        self._stores.append(store)
        return store

    def pair(self, clock: Clock | None = None) -> tuple[RequestStore, RequestStore]:
        """Two stores on the same data (for memory: one store twice)."""
        first = self.open(clock)
        return (first, first) if self.url is None else (first, self.open(clock))

    def close(self) -> None:
        for store in self._stores:
            store.close()
