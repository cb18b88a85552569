"""The event streams of requests (and missions): each follower gets it now, then every change.

``RequestFeed`` keeps, per request, the queues of the clients following it
(``GET /v1/requests/{id}/events``); the actors publish each change to it.
``MissionFeed`` (in ``iaas/missions``) is the same for missions.

A client's queue is registered by ``subscribe``, a context manager that the
HTTP route holds for as long as its response lasts (a FastAPI dependency with
``yield``), and removed when it ends, the client gone included. It was removed
by the stream's async generator instead: a client that went away while a
change was on its way left that generator suspended, never closed, so the
queue (and the memory of the stream) stayed until Python's cycle collector
happened to find it (issue 25: 188 of 500 closed streams still registered 30 s
later).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator
from typing import Generic, Protocol, TypeVar

from robocloud.domain import is_final
from robocloud.storage import RequestRecord


class Followed(Protocol):
    """What a feed follows: a request, or a mission (same final states)."""

    @property
    def id(self) -> str: ...

    @property
    def state(self) -> str: ...


R = TypeVar("R", bound=Followed)


class Feed(Generic[R]):
    def __init__(self) -> None:
        # one follower's changes each; None: the IaaS stops
        self._listeners: dict[str, set[asyncio.Queue[R | None]]] = {}

    def publish(self, record: R) -> None:
        for queue in self._listeners.get(record.id, ()):
            queue.put_nowait(record)

    def close(self) -> None:
        """End every stream (the IaaS stops)."""
        for queues in self._listeners.values():
            for queue in queues:
                queue.put_nowait(None)

    def following(self) -> int:
        """How many streams are open now."""
        return sum(len(queues) for queues in self._listeners.values())

    @contextlib.contextmanager
    def subscribe(self, key: str) -> Iterator[asyncio.Queue[R | None]]:
        """A queue of the changes of ``key`` (a request, a mission), kept until the block ends."""
        queue: asyncio.Queue[R | None] = asyncio.Queue()
        self._listeners.setdefault(key, set()).add(queue)
        try:
            yield queue
        finally:
            queues = self._listeners.get(key)
            if queues is not None:
                queues.discard(queue)
                if not queues:
                    del self._listeners[key]

    @staticmethod
    async def follow(
        updates: asyncio.Queue[R | None], read: Callable[[], Awaitable[R]]
    ) -> AsyncIterator[R]:
        """It now (``read``), then each change ``updates`` brings, until it is final."""
        record = await read()
        yield record
        while not is_final(record.state):
            update = await updates.get()
            if update is None:
                return
            record = update
            yield record


class RequestFeed(Feed[RequestRecord]):
    """The requests' event streams."""


Updates = asyncio.Queue[RequestRecord | None]  # one request follower's changes
