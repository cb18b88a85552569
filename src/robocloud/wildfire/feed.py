"""The wildfire server's background work and its live stream to the pages.

Three kinds of loop, one tick apart each, owned by one task group in the
app's lifespan:

- one per IaaS: its health, then (when it answers) its newest requests and
  any unfinished request of it not read lately, into the model (alerts);
  until one IaaS has given them, the task's bounds from its OpenAPI document
  (``task_limits.py``), tried again a minute later where it failed;
- the fleet: the robots and the live clouds, read from the first IaaS that
  answers (one read for every page, however many are open);
- the publisher: the model's delta, sent to every open page.

A slow or frozen IaaS holds up only its own loop. Each page gets a
server-sent event stream (``GET /api/live``): ``event: snapshot`` first, then
``event: delta`` every tick, gzip-compressed as one stream, so what repeats
from one delta to the next (robot ids, keys) costs almost nothing.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import time
import zlib
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass, field

from robocloud.wildfire.iaas_client import IaasError
from robocloud.wildfire.iaas_pool import Endpoint, IaasPool
from robocloud.wildfire.live import LiveModel, dumps
from robocloud.wildfire.task_limits import task_limits

log = logging.getLogger(__name__)

NEWEST_REQUESTS = 20
# Unfinished requests beyond the newest are read one by one, this many a tick at most.
SINGLE_READS_PER_TICK = 10
QUEUE_LENGTH = 30
# An IaaS whose OpenAPI document gave no task bounds is asked again this much later.
SCHEMA_RETRY_S = 60.0


class TooManyPages(Exception):
    pass


@dataclass(eq=False)  # each page's stream is its own, hashed by identity
class Subscriber:
    queue: asyncio.Queue[bytes] = field(default_factory=lambda: asyncio.Queue(QUEUE_LENGTH))
    lagging: bool = False

    def offer(self, event: bytes) -> None:
        try:
            self.queue.put_nowait(event)
        except asyncio.QueueFull:
            # A page that cannot keep up starts over from a snapshot.
            self.lagging = True


def event(name: str, data: bytes) -> bytes:
    return b"event: " + name.encode() + b"\ndata: " + data + b"\n\n"


class LiveFeed:
    def __init__(self, pool: IaasPool, model: LiveModel,
                 clock: Callable[[], float] = time.time) -> None:
        self.pool = pool
        self.model = model
        self.settings = model.settings
        self.clock = clock
        self.subscribers: set[Subscriber] = set()
        self.sent_bytes = 0  # to every page, compressed: the field link's cost
        self._schema_due: dict[int, float] = {}  # endpoint index -> when to ask for its schema

    async def run(self) -> None:
        async with asyncio.TaskGroup() as group:
            for endpoint in self.pool.endpoints:
                group.create_task(self._every_tick(functools.partial(self.watch, endpoint)))
            group.create_task(self._every_tick(self.read_fleet))
            group.create_task(self._every_tick(self.publish))

    async def _every_tick(self, step: Callable[[], Awaitable[None]]) -> None:
        while True:
            started = time.monotonic()
            try:
                await step()
            except Exception:
                log.exception("a live update step failed; it runs again next tick")
            await asyncio.sleep(max(0.05, self.settings.tick - (time.monotonic() - started)))

    # --- reading ------------------------------------------------------------------
    async def watch(self, endpoint: Endpoint) -> None:
        """One IaaS: its health, its newest requests, its unfinished ones."""
        await self.pool.check(endpoint)
        if not endpoint.ok:
            return
        timeout = self.settings.poll_timeout
        if self.model.limits is None:
            await self.read_limits(endpoint)
        try:
            page = await endpoint.client.list_requests({"limit": str(NEWEST_REQUESTS)}, timeout)
        except IaasError as error:
            self.pool.mark(endpoint, error)
            return
        now = self.clock()
        listed = set()
        for item in page["items"]:
            if isinstance(item, dict) and isinstance(item.get("id"), str):
                listed.add(item["id"])
                self.pool.remember(item["id"], endpoint)
                self.model.ingest_request(item, endpoint.cloud, now)
        due = sorted(
            (checked, request_id) for request_id, _, checked in self.model.active_requests()
            if request_id not in listed and self.pool.home_of(request_id) is endpoint
            and now - checked >= self.settings.tick
        )[:SINGLE_READS_PER_TICK]
        for _, request_id in due:
            try:
                record = await endpoint.client.get_request(request_id, timeout)
            except IaasError as error:
                self.pool.mark(endpoint, error)
                if not endpoint.ok:
                    return
                continue
            self.model.ingest_request(record, endpoint.cloud, self.clock())

    async def read_limits(self, endpoint: Endpoint) -> None:
        """The task's bounds, from this IaaS's OpenAPI document, for the page's form."""
        now = time.monotonic()
        if now < self._schema_due.get(endpoint.index, 0.0):
            return
        self._schema_due[endpoint.index] = now + SCHEMA_RETRY_S
        try:
            spec = await endpoint.client.openapi(self.settings.poll_timeout)
        except IaasError as error:
            log.debug("no task bounds from %s: %s", endpoint.url, error.detail)
            return
        self.model.limits = task_limits(spec)

    async def read_fleet(self) -> None:
        primary = self.pool.primary()
        if primary is None:
            return
        timeout = self.settings.poll_timeout
        answers = await asyncio.gather(
            primary.client.robots("federation", timeout), primary.client.clouds(timeout),
            return_exceptions=True)
        now = self.clock()
        robots, clouds = answers
        for answer in answers:
            if isinstance(answer, IaasError):
                self.pool.mark(primary, answer)
                return
            if isinstance(answer, BaseException):
                raise answer
        assert isinstance(robots, list) and isinstance(clouds, list)
        self.model.ingest_fleet(robots, now)
        self.model.ingest_clouds(clouds, now)

    # --- the pages ------------------------------------------------------------------
    async def publish(self) -> None:
        self.model.ingest_endpoints([e.as_json() for e in self.pool.endpoints],
                                    self.pool.time_scale())
        delta = event("delta", dumps(self.model.publish(self.clock())))
        for subscriber in self.subscribers:
            subscriber.offer(delta)

    def snapshot_event(self) -> bytes:
        return event("snapshot", dumps(self.model.snapshot(self.clock())))

    def subscribe(self) -> tuple[Subscriber, bytes]:
        if len(self.subscribers) >= self.settings.max_live_pages:
            raise TooManyPages
        subscriber = Subscriber()
        self.subscribers.add(subscriber)
        return subscriber, self.snapshot_event()

    async def stream(self, subscriber: Subscriber, first: bytes, compress: bool
                     ) -> AsyncIterator[bytes]:
        """The bytes of one page's event stream; one gzip stream, flushed at each event."""
        compressor = zlib.compressobj(6, zlib.DEFLATED, 31) if compress else None

        def encode(data: bytes) -> bytes:
            out = data if compressor is None else (
                compressor.compress(data) + compressor.flush(zlib.Z_SYNC_FLUSH))
            self.sent_bytes += len(out)
            return out

        try:
            yield encode(b"retry: 2000\n\n" + first)
            while True:
                data = await subscriber.queue.get()
                if subscriber.lagging:
                    while not subscriber.queue.empty():
                        subscriber.queue.get_nowait()
                    subscriber.lagging = False
                    data = self.snapshot_event()
                yield encode(data)
        finally:
            self.subscribers.discard(subscriber)
