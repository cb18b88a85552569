"""The event streams of requests (and missions): each follower gets it now, then every change.

``RequestFeed`` keeps, per request, the queues of the clients following it
(``GET /v1/requests/{id}/events``); the actors publish each change to it. A
client that goes away takes its queue with it.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Awaitable, Callable
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

    async def follow(self, request_id: str, read: Callable[[], Awaitable[R]]) -> AsyncIterator[R]:
        """The request now (``read``), then after each change, until it is final."""
        queue: asyncio.Queue[R | None] = asyncio.Queue()
        self._listeners.setdefault(request_id, set()).add(queue)
        try:
            record = await read()
            yield record
            while not is_final(record.state):
                update = await queue.get()
                if update is None:
                    return
                record = update
                yield record
        finally:
            queues = self._listeners.get(request_id)
            if queues is not None:
                queues.discard(queue)
                if not queues:
                    del self._listeners[request_id]


class RequestFeed(Feed[RequestRecord]):
    """The requests' event streams."""
