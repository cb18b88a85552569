"""The capability names robots have announced: grow-only and bounded.

Each cloud keeps the names its own robots have announced since its IaaS
started and says them in its ``CloudInfo``; an IaaS refuses at POST a task
that names a capability no robot of the federation has ever announced
(``robocloud.iaas.capabilities``). Grow-only, because a robot that went
offline may come back; bounded (``MAX_NAMES``, the most one message carries),
because robots choose the names: once full, nothing is refused for being
unknown (the IaaS cannot tell).
"""

from __future__ import annotations

import threading
from collections.abc import Iterable

from robocloud.domain import Robot
from robocloud.federation.messages import MAX_ITEMS

MAX_NAMES = MAX_ITEMS


class Announced:
    """A set of capability names that only grows, up to ``limit``; safe from any thread."""

    def __init__(self, limit: int = MAX_NAMES) -> None:
        self._limit = limit
        self._names: set[str] = set()
        self._sorted: list[str] = []
        self._lock = threading.Lock()

    def learn(self, names: Iterable[str]) -> None:
        fresh = [n for n in names if n not in self._names]
        if not fresh:
            return
        with self._lock:
            for name in fresh:
                if len(self._names) >= self._limit:
                    break
                self._names.add(name)
            self._sorted = sorted(self._names)

    def learn_robots(self, robots: Iterable[Robot]) -> None:
        for robot in robots:
            self.learn(robot.capabilities)

    def __contains__(self, name: object) -> bool:
        return name in self._names

    def names(self) -> list[str]:
        """Sorted (a copy replaced whole on change: read without the lock)."""
        return self._sorted

    @property
    def full(self) -> bool:
        return len(self._names) >= self._limit
