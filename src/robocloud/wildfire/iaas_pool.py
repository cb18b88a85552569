"""Several IaaSs as one: health, where each request lives, truthful sends, one request list.

The wildfire server may be given several IaaSs of the same federation (one
per cloud, each accepting the application's key) and keeps working while any
one answers:

- **Health**: each IaaS's ``/healthz`` is read every tick; the first that
  answers, in the order given, is where new requests go and where the fleet
  is read.
- **Sends**: a send carries the page's ``Idempotency-Key``. Once a send may
  have reached an IaaS (it was sent and no answer came), the key is pinned to
  that IaaS: every retry goes there, so the IaaS finds the request it may
  already hold instead of another IaaS making a second one. A send refused
  before anything left (connection refused) moves on to the next IaaS.
- **Requests**: each request lives at the IaaS that received it; the pool
  remembers where, and asks each IaaS in turn for an id it has not seen.
- **The list**: one newest-first list over every IaaS, paged with a cursor
  that holds each IaaS's own cursor.

Missions (several tasks planned as one) follow the same rules as requests:
the same pinned sends, the same home, the same merged list.
"""

from __future__ import annotations

import asyncio
import re
import time
from collections import OrderedDict
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import httpx

from robocloud.domain.request import REQUEST_STATES
from robocloud.wildfire.config import WildfireSettings
from robocloud.wildfire.iaas_client import (
    REQUEST_ID,
    IaasBusy,
    IaasClient,
    IaasError,
    IaasUnreachable,
    MissionEvents,
)

MAX_REMEMBERED = 20_000
MAX_PINNED_KEYS = 10_000
MAX_LIST_LIMIT = 200
CURSOR_PART = re.compile(r"(\d{1,3}):(-|" + REQUEST_ID.pattern + r")")
EXHAUSTED = "-"


@dataclass
class Endpoint:
    """One IaaS and what its last health check said."""

    index: int
    url: str
    client: IaasClient
    cloud: str | None = None
    ok: bool | None = None  # None until the first check
    since: float = 0.0  # wall time ok last changed
    error: str | None = None
    time_scale: float | None = None

    def name(self) -> str:
        return f"{self.cloud} ({self.url})" if self.cloud else self.url

    def as_json(self) -> dict[str, Any]:
        return {
            "url": self.url, "cloud": self.cloud, "ok": self.ok, "since": round(self.since, 3),
            "error": self.error, "time_scale": self.time_scale,
        }


@dataclass
class Pin:
    endpoint: int
    maybe_delivered: bool


class IaasPool:
    def __init__(
        self, settings: WildfireSettings, transport: httpx.AsyncBaseTransport | None = None
    ) -> None:
        self.settings = settings
        self.endpoints = [
            Endpoint(i, url, IaasClient(url, settings.api_key, timeout=settings.timeout,
                                        transport=transport))
            for i, url in enumerate(settings.iaas)
        ]
        self._where: OrderedDict[str, int] = OrderedDict()
        self._pins: OrderedDict[str, Pin] = OrderedDict()

    async def aclose(self) -> None:
        for endpoint in self.endpoints:
            await endpoint.client.aclose()

    # --- health ---------------------------------------------------------------
    async def check_health(self) -> None:
        await asyncio.gather(*(self.check(e) for e in self.endpoints))

    async def check(self, endpoint: Endpoint) -> None:
        try:
            health = await endpoint.client.health(timeout=self.settings.poll_timeout)
        except IaasError as error:
            self.mark(endpoint, error)
            return
        if isinstance(health.get("cloud"), str):
            endpoint.cloud = health["cloud"]
        scale = health.get("time_scale", 1.0)
        endpoint.time_scale = float(scale) if isinstance(scale, int | float) and scale > 0 else None
        self._set(endpoint, True, None)

    def mark(self, endpoint: Endpoint, error: IaasError) -> None:
        """An answer failed: an IaaS that cannot be reached is down until it answers again."""
        if isinstance(error, IaasUnreachable) or error.status >= 500:
            self._set(endpoint, False, error.detail)

    def _set(self, endpoint: Endpoint, ok: bool, error: str | None) -> None:
        if endpoint.ok is not ok:
            endpoint.since = time.time()
        endpoint.ok = ok
        endpoint.error = error

    def ordered(self) -> list[Endpoint]:
        """Healthy IaaSs first (in the order given), then unchecked ones, then failing ones."""
        rank = {True: 0, None: 1, False: 2}
        return sorted(self.endpoints, key=lambda e: (rank[e.ok], e.index))

    def primary(self) -> Endpoint | None:
        """Where new requests go and the fleet is read: the first healthy IaaS."""
        healthy = [e for e in self.endpoints if e.ok]
        return healthy[0] if healthy else None

    def time_scale(self) -> float | None:
        for endpoint in self.ordered():
            if endpoint.ok and endpoint.time_scale:
                return endpoint.time_scale
        return None

    # --- where requests live --------------------------------------------------
    def remember(self, request_id: str, endpoint: Endpoint) -> None:
        self._where[request_id] = endpoint.index
        self._where.move_to_end(request_id)
        while len(self._where) > MAX_REMEMBERED:
            self._where.popitem(last=False)

    def home_of(self, request_id: str) -> Endpoint | None:
        index = self._where.get(request_id)
        return None if index is None else self.endpoints[index]

    # --- calls on the operator's behalf ----------------------------------------
    async def create_request(self, body: bytes, key: str | None) -> tuple[dict[str, Any], Endpoint]:
        """Send a task; a key that may already be at an IaaS only ever goes back there."""
        return await self._create(lambda e: e.client.create_request(body, key), key)

    async def create_mission(self, body: bytes, key: str | None) -> tuple[dict[str, Any], Endpoint]:
        """Send a mission, as a task is sent."""
        return await self._create(lambda e: e.client.create_mission(body, key), key)

    async def _create(self, send: Callable[[Endpoint], Awaitable[dict[str, Any]]],
                      key: str | None) -> tuple[dict[str, Any], Endpoint]:
        pin = self._pins.get(key) if key else None
        if pin is not None and pin.maybe_delivered:
            candidates = [self.endpoints[pin.endpoint]]
        else:
            candidates = self.ordered()
        last: IaasError | None = None
        for endpoint in candidates:
            try:
                record = await send(endpoint)
            except IaasUnreachable as error:
                self.mark(endpoint, error)
                if error.maybe_delivered:
                    self._pin(key, endpoint, maybe_delivered=True)
                    raise
                last = error
                continue
            except IaasBusy as error:
                if pin is not None and pin.maybe_delivered:
                    # An earlier send may still be on its way there: the key
                    # not found now does not mean it never will be.
                    raise IaasError(error.status, error.detail) from None
                # Too busy to take it, and nothing stored: the next IaaS may take it.
                last = error
                continue
            except IaasError as error:
                if error.status >= 500:
                    # The IaaS failed inside: it may have stored the request first.
                    self._pin(key, endpoint, maybe_delivered=True)
                raise
            self._pin(key, endpoint, maybe_delivered=True)
            if isinstance(record.get("id"), str):
                self.remember(record["id"], endpoint)
            return record, endpoint
        assert last is not None
        raise last

    def _pin(self, key: str | None, endpoint: Endpoint, *, maybe_delivered: bool) -> None:
        if not key:
            return
        self._pins[key] = Pin(endpoint.index, maybe_delivered)
        self._pins.move_to_end(key)
        while len(self._pins) > MAX_PINNED_KEYS:
            self._pins.popitem(last=False)

    async def get_request(
        self, request_id: str, timeout: float | None = None
    ) -> tuple[dict[str, Any], Endpoint]:
        return await self._at_home(request_id, lambda e: e.client.get_request(request_id, timeout))

    async def cancel_request(self, request_id: str) -> tuple[dict[str, Any], Endpoint]:
        return await self._at_home(request_id, lambda e: e.client.cancel_request(request_id))

    async def get_mission(
        self, mission_id: str, timeout: float | None = None
    ) -> tuple[dict[str, Any], Endpoint]:
        return await self._at_home(mission_id, lambda e: e.client.get_mission(mission_id, timeout),
                                   "mission")

    async def cancel_mission(self, mission_id: str) -> tuple[dict[str, Any], Endpoint]:
        return await self._at_home(mission_id, lambda e: e.client.cancel_mission(mission_id),
                                   "mission")

    async def mission_events(self, mission_id: str) -> MissionEvents:
        """The mission's event stream, from the IaaS that holds it (found first if need be)."""
        home = self.home_of(mission_id)
        if home is None:
            _, home = await self.get_mission(mission_id, self.settings.poll_timeout)
        try:
            return await home.client.mission_events(mission_id)
        except IaasError as error:
            self.mark(home, error)
            raise

    async def _at_home(self, request_id: str, call: Any, what: str = "request"
                       ) -> tuple[dict[str, Any], Endpoint]:
        home = self.home_of(request_id)
        if home is not None:
            try:
                return await call(home), home
            except IaasError as error:
                self.mark(home, error)
                raise
        # Not seen yet: ask each IaaS; a 404 from one says nothing of the others.
        unreachable: IaasError | None = None
        not_found: IaasError | None = None
        for endpoint in self.ordered():
            try:
                record = await call(endpoint)
            except IaasError as error:
                self.mark(endpoint, error)
                if error.status == 404:
                    not_found = error
                    continue
                if isinstance(error, IaasUnreachable) or error.status >= 500:
                    unreachable = unreachable or error
                    continue
                raise
            self.remember(request_id, endpoint)
            return record, endpoint
        if unreachable is not None:
            raise IaasError(
                502,
                f"no IaaS that answered knows the {what} {request_id!r}, and "
                f"{unreachable.detail.rstrip('.')}: it may be there.",
            )
        assert not_found is not None
        raise not_found

    # --- one list over every IaaS ----------------------------------------------
    async def list_requests(
        self,
        state: str | None,
        limit: int,
        cursor: str | None,
        timeout: float | None = None,
    ) -> dict[str, Any]:
        """Newest first over every IaaS; ``next`` pages on; ``missing`` names silent IaaSs."""
        if state is not None and state not in REQUEST_STATES:
            raise IaasError(
                422, f"state must be one of {', '.join(REQUEST_STATES)}; {state!r} is not a state."
            )
        return await self._list("requests", state, limit, cursor, timeout)

    async def list_missions(
        self, state: str | None, limit: int, cursor: str | None, timeout: float | None = None,
    ) -> dict[str, Any]:
        """As ``list_requests``; a mission's states are the IaaS's to check."""
        return await self._list("missions", state, limit, cursor, timeout)

    async def _list(
        self, kind: str, state: str | None, limit: int, cursor: str | None,
        timeout: float | None,
    ) -> dict[str, Any]:
        if not 1 <= limit <= MAX_LIST_LIMIT:
            raise IaasError(422, f"limit must be a whole number from 1 to {MAX_LIST_LIMIT}.")
        positions = self._parse_cursor(cursor)
        wanted = [e for e in self.endpoints if positions.get(e.index) != EXHAUSTED]

        async def page_of(endpoint: Endpoint) -> dict[str, Any]:
            params = {"limit": str(limit)}
            if state:
                params["state"] = state
            before = positions.get(endpoint.index)
            if before:
                params["before"] = before
            if kind == "missions":
                return await endpoint.client.list_missions(params, timeout)
            return await endpoint.client.list_requests(params, timeout)

        answers = await asyncio.gather(*(page_of(e) for e in wanted), return_exceptions=True)
        merged: list[tuple[datetime, str, int, dict[str, Any]]] = []
        fetched: dict[int, dict[str, Any]] = {}
        missing: list[str] = []
        for endpoint, answer in zip(wanted, answers, strict=True):
            if isinstance(answer, IaasError):
                self.mark(endpoint, answer)
                if kind == "missions" and answer.status == 404:
                    # An IaaS older than missions: it holds none.
                    missing.append(f"{endpoint.name()} does not offer missions (its IaaS has "
                                   f"no /v1/missions).")
                    continue
                if isinstance(answer, IaasUnreachable) or answer.status >= 500:
                    missing.append(f"the {kind} held by {endpoint.name()} are not shown: "
                                   f"{answer.detail}")
                    continue
                raise answer
            if isinstance(answer, BaseException):
                raise answer
            fetched[endpoint.index] = answer
            for item in answer["items"]:
                if isinstance(item, dict) and isinstance(item.get("id"), str):
                    self.remember(item["id"], endpoint)
                    merged.append((_when(item), item["id"], endpoint.index, item))
        merged.sort(key=lambda m: (m[0], m[1]), reverse=True)
        page = merged[:limit]
        for index, answer in fetched.items():
            shown = [m for m in page if m[2] == index]
            if shown:
                positions[index] = shown[-1][1]
            if len(shown) == len(answer["items"]) and not answer.get("next"):
                positions[index] = EXHAUSTED
        live = [i for i in fetched if positions.get(i) != EXHAUSTED]
        # An IaaS without a position is read from its newest request again.
        next_cursor = ",".join(f"{i}:{p}" for i, p in sorted(positions.items())) if live else None
        return {
            "items": [(m[3], self.endpoints[m[2]]) for m in page],
            "next": next_cursor,
            "missing": missing,
        }

    def _parse_cursor(self, cursor: str | None) -> dict[int, str]:
        positions: dict[int, str] = {}
        if not cursor:
            return positions
        for part in cursor.split(","):
            match = CURSOR_PART.fullmatch(part)
            if not match or int(match.group(1)) >= len(self.endpoints) or int(
                    match.group(1)) in positions:
                raise IaasError(422, "before: this cursor was not given by this server; "
                                     "start again from the first page.")
            positions[int(match.group(1))] = match.group(2)
        return positions


def _when(item: dict[str, Any]) -> datetime:
    created = item.get("created_at")
    if isinstance(created, int | float) and not isinstance(created, bool):
        # A mission's times are seconds since the epoch.
        try:
            return datetime.fromtimestamp(created, UTC)
        except (OverflowError, OSError, ValueError):
            return datetime.min.replace(tzinfo=UTC)
    try:
        when = datetime.fromisoformat(str(created))
    except ValueError:
        return datetime.min.replace(tzinfo=UTC)
    return when if when.tzinfo else when.replace(tzinfo=UTC)
