"""The IaaS's writes to its store, taken in turns: ``StoreWrites``.

Every request writes five or six times in its life (created, selecting,
dispatched, underway, completed, and notes), each from the event loop. Made
one by one, each write costs a hand-off to a worker thread and one back, a
transaction with its BEGIN and COMMIT, and, on SQLite, a turn at the one write
lock. Here the writes the loop asks for queue up; one thread takes all those
waiting and hands them to the store together (``RequestStore.together``:
one transaction on SQLite, each write in a savepoint), then gives every
answer back to the loop in one call. Under load a turn carries tens of writes
for the price of one; alone, a write costs what it did.

Each write is still all or nothing and answered with its own value or error.
With one thread taking turns (SQLite) writes are made in the order they were
asked for. On PostgreSQL several threads take turns side by side, so writes of
two turns may be made in either order; a request's actor waits for each of
its writes before it asks for the next, so its own stay in order.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable
from concurrent.futures import Executor
from functools import partial
from typing import Any, TypeVar

from robocloud.storage import RequestStore, StoreUnavailable
from robocloud.storage.store import Outcome

T = TypeVar("T")
TURN_MAX = 64  # writes handed to the store in one turn at most


class StoreWrites:
    """Queues the loop's store writes; threads of ``executor`` (one unless told) make them."""

    def __init__(
        self,
        store: RequestStore,
        executor: Executor,
        failed: Callable[[Callable[..., Any]], None] = lambda function: None,
        takers: int = 1,
    ) -> None:
        self._store = store
        self._executor = executor
        self._failed = failed  # told of each write that found the store unavailable
        # Threads taking turns at once, at most: one where the store has one
        # writer at a time (SQLite), more where writers run side by side
        # (PostgreSQL, whose ``together`` makes each call alone).
        self._most = takers
        self._lock = threading.Lock()
        self._waiting: list[tuple[Callable[..., Any], Callable[[], Any], asyncio.Future[Any]]] = []
        self._takers = 0  # threads taking turns now

    async def __call__(self, function: Callable[..., T], *args: Any) -> T:
        """``function(*args)`` (a method of the store), made in the next turn."""
        loop = asyncio.get_running_loop()
        answer: asyncio.Future[T] = loop.create_future()
        with self._lock:
            self._waiting.append((function, partial(function, *args), answer))
            start = self._takers < self._most
            if start:
                self._takers += 1
        if start:
            try:
                self._executor.submit(self._take_turns, loop)
            except RuntimeError:  # the executor is shut down: the IaaS is stopping
                with self._lock:
                    self._takers -= 1
                raise
        return await answer

    def _take_turns(self, loop: asyncio.AbstractEventLoop) -> None:
        """On the store's thread: hand every waiting write to the store, until none waits."""
        while True:
            with self._lock:
                turn = self._waiting[:TURN_MAX]
                del self._waiting[:TURN_MAX]
                if not turn:
                    self._takers -= 1
                    return
            try:
                outcomes = self._store.together([call for _, call, _ in turn])
            except Exception as error:  # the store broke its promise: every write gets it
                outcomes = [Outcome(error=error)] * len(turn)
            try:
                loop.call_soon_threadsafe(self._answer, turn, outcomes)
            except RuntimeError:  # the loop is closed: nobody waits any more
                with self._lock:
                    self._takers -= 1
                return

    def _answer(
        self,
        turn: list[tuple[Callable[..., Any], Callable[[], Any], asyncio.Future[Any]]],
        outcomes: list[Outcome],
    ) -> None:
        """On the loop: every write of a turn gets its answer."""
        for (function, _, answer), outcome in zip(turn, outcomes, strict=True):
            if isinstance(outcome.error, StoreUnavailable):
                self._failed(function)
            if answer.done():  # its caller was cancelled
                continue
            if outcome.error is not None:
                answer.set_exception(outcome.error)
            else:
                answer.set_result(outcome.value)
