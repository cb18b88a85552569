"""One IaaS's HTTP API as the wildfire server calls it: one client, its key attached.

The errors it raises, each carrying what the page needs to show::

    IaasError               the IaaS answered with an error: its status and its sentence
    └── IaasUnreachable     no usable answer (refused, timed out, not JSON): 502 or 504
                            ``maybe_delivered`` says whether the IaaS may have
                            acted on the call all the same (it was sent, and
                            then the answer never came)

``robocloud.wildfire.app`` maps them to HTTP responses, in one place.

Requests (``/v1/requests``) and missions (``/v1/missions``, several tasks
planned as one, docs/model.md) are called alike; a mission's event stream
(``GET /v1/missions/{id}/events``) is read as :class:`MissionEvents`.
"""

from __future__ import annotations

import json
import re
import time
from collections.abc import AsyncIterator
from typing import Any

import httpx

from robocloud.errors import Busy

# Request and mission ids travel inside a path: anything else could walk to another route.
REQUEST_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,127}")
LIST_PARAMETERS = ("state", "limit", "before")
# One event of a mission's stream is one mission: larger is not an IaaS's.
MAX_EVENT_BYTES = 4 * 1024 * 1024
# 100,000 robots are about 30 MB of JSON: an answer beyond this is not an IaaS's.
MAX_ANSWER_BYTES = 64 * 1024 * 1024
# GET /v1/robots comes in pages (the Link header's rel="next"): the largest an
# IaaS gives, and a bound on how many are followed (100,000 robots).
ROBOTS_PAGE = 10_000
MAX_ROBOT_PAGES = 10
# A read whose timeout was noticed this much after it was due timed out while
# this process stood still (stopped, swapped out, a paused VM), not because the
# IaaS was slow: the read is tried once more.
STALL_MARGIN = 1.0

# Errors raised before a byte of the call left: the IaaS cannot have acted on it.
NOT_SENT = (httpx.ConnectError, httpx.ConnectTimeout, httpx.PoolTimeout, httpx.UnsupportedProtocol)


class IaasError(Exception):
    """The IaaS answered ``status``; ``detail`` is its sentence for the user."""

    def __init__(self, status: int, detail: str) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail


class IaasUnreachable(IaasError):
    def __init__(self, url: str, cause: str, *, maybe_delivered: bool, timed_out: bool) -> None:
        super().__init__(504 if timed_out else 502, f"the IaaS at {url} {cause}.")
        self.url = url
        self.maybe_delivered = maybe_delivered


class IaasBusy(IaasError):
    """The IaaS was too busy to take a new request (503 with ``Busy.HEADER``): nothing stored."""

    def __init__(self, detail: str) -> None:
        super().__init__(503, detail)


class IaasClient:
    """Thin async calls to one IaaS; answers are parsed JSON."""

    def __init__(
        self,
        base_url: str,
        api_key: str | None,
        *,
        timeout: float = 10.0,
        transport: httpx.AsyncBaseTransport | None = None,
    ) -> None:
        self.base_url = base_url.rstrip("/")
        headers = {"Accept": "application/json", "User-Agent": "robocloud-wildfire"}
        if api_key:
            headers["Authorization"] = f"Bearer {api_key}"
        self._http = httpx.AsyncClient(
            base_url=self.base_url, headers=headers, timeout=timeout, transport=transport
        )
        self.timeout = timeout
        self.failures = 0  # calls without a usable answer, or answered 5xx (the metrics)

    async def aclose(self) -> None:
        await self._http.aclose()

    async def health(self, timeout: float | None = None) -> dict[str, Any]:
        return _object(await self._call("GET", "/healthz", timeout=timeout), self.base_url)

    async def openapi(self, timeout: float | None = None) -> dict[str, Any]:
        """The IaaS's OpenAPI document (open, like ``/healthz``): the task's bounds."""
        return _object(await self._call("GET", "/openapi.json", timeout=timeout), self.base_url)

    async def clouds(self, timeout: float | None = None) -> list[Any]:
        return _list(await self._call("GET", "/v1/clouds", timeout=timeout), self.base_url)

    async def robots(self, scope: str = "federation", timeout: float | None = None) -> list[Any]:
        """Every robot the IaaS sees: its own and, in a federation, every live cloud's.

        Page after page while the IaaS names a next one (``Link: <...>; rel="next"``,
        a path of the same route); an IaaS that does not page answers in one.
        """
        robots: list[Any] = []
        path = f"/v1/robots?scope={scope}&limit={ROBOTS_PAGE}"
        for _ in range(MAX_ROBOT_PAGES):
            answer, following = await self._exchange("GET", path, timeout=timeout)
            robots += _list(answer, self.base_url)
            if following is None or not following.startswith("/v1/robots?"):
                break
            path = following
        return robots

    async def list_requests(
        self, params: dict[str, str], timeout: float | None = None
    ) -> dict[str, Any]:
        kept = {k: v for k, v in params.items() if k in LIST_PARAMETERS}
        answer = await self._call("GET", "/v1/requests", params=kept, timeout=timeout)
        page = _object(answer, self.base_url)
        if not isinstance(page.get("items"), list):
            raise _not_json(self.base_url, "its request list has no items")
        return page

    async def create_request(self, body: bytes, idempotency_key: str | None) -> dict[str, Any]:
        return await self._create("/v1/requests", body, idempotency_key)

    async def get_request(self, request_id: str, timeout: float | None = None) -> dict[str, Any]:
        answer = await self._call("GET", f"/v1/requests/{checked_id(request_id)}", timeout=timeout)
        return _object(answer, self.base_url)

    async def cancel_request(self, request_id: str) -> dict[str, Any]:
        answer = await self._call("POST", f"/v1/requests/{checked_id(request_id)}/cancel")
        return _object(answer, self.base_url)

    # --- missions: several tasks planned as one ----------------------------------
    async def list_missions(
        self, params: dict[str, str], timeout: float | None = None
    ) -> dict[str, Any]:
        """The IaaS's ``{"missions": [...], "next": ...}``, as ``{"items": ..., "next": ...}``."""
        kept = {k: v for k, v in params.items() if k in LIST_PARAMETERS}
        answer = await self._call("GET", "/v1/missions", params=kept, timeout=timeout)
        page = _object(answer, self.base_url)
        if not isinstance(page.get("missions"), list):
            raise _not_json(self.base_url, "its mission list has no missions")
        return {"items": page["missions"], "next": page.get("next")}

    async def create_mission(self, body: bytes, idempotency_key: str | None) -> dict[str, Any]:
        return await self._create("/v1/missions", body, idempotency_key)

    async def get_mission(self, mission_id: str, timeout: float | None = None) -> dict[str, Any]:
        path = f"/v1/missions/{checked_id(mission_id, 'mission')}"
        return _object(await self._call("GET", path, timeout=timeout), self.base_url)

    async def cancel_mission(self, mission_id: str) -> dict[str, Any]:
        path = f"/v1/missions/{checked_id(mission_id, 'mission')}"
        return _object(await self._call("DELETE", path), self.base_url)

    async def mission_events(self, mission_id: str) -> MissionEvents:
        """The mission's event stream, open: its status was checked (an error is raised here)."""
        path = f"/v1/missions/{checked_id(mission_id, 'mission')}/events"
        # The stream is quiet between changes: no read timeout, the connection's own.
        request = self._http.build_request(
            "GET", path, headers={"Accept": "text/event-stream"},
            timeout=httpx.Timeout(self.timeout, read=None))
        try:
            answer = await self._http.send(request, stream=True)
        except httpx.HTTPError as error:
            self.failures += 1
            raise IaasUnreachable(self.base_url, f"cannot be reached ({_cause(error)})",
                                  maybe_delivered=False,
                                  timed_out=isinstance(error, httpx.TimeoutException)) from None
        if answer.status_code >= 400:
            content = await _bounded(answer)
            await answer.aclose()
            if answer.status_code >= 500:
                self.failures += 1
            raise IaasError(answer.status_code,
                            _sentence(answer.status_code, answer.reason_phrase, content or b""))
        return MissionEvents(answer, mission_id)

    async def _create(self, path: str, body: bytes, idempotency_key: str | None
                      ) -> dict[str, Any]:
        headers = {"Content-Type": "application/json"}
        if idempotency_key:
            headers["Idempotency-Key"] = idempotency_key
        answer = await self._call("POST", path, content=body, headers=headers)
        return _object(answer, self.base_url)

    async def _call(
        self, method: str, path: str, *, timeout: float | None = None, **kwargs: Any
    ) -> Any:
        return (await self._exchange(method, path, timeout=timeout, **kwargs))[0]

    async def _exchange(
        self, method: str, path: str, *, timeout: float | None = None, **kwargs: Any
    ) -> tuple[Any, str | None]:
        """The parsed answer, and the URL of its ``Link: <...>; rel="next"`` if it has one."""
        try:
            started = time.monotonic()
            try:
                return await self._exchange_once(method, path, timeout=timeout, **kwargs)
            except IaasUnreachable as error:
                limit = self.timeout if timeout is None else timeout
                stalled = time.monotonic() - started > limit + STALL_MARGIN
                if not (method == "GET" and error.status == 504 and stalled):
                    raise
            return await self._exchange_once(method, path, timeout=timeout, **kwargs)
        except IaasError as error:
            busy = isinstance(error, IaasBusy)  # it answers: it is not failing
            if isinstance(error, IaasUnreachable) or (error.status >= 500 and not busy):
                self.failures += 1
            raise

    async def _exchange_once(
        self, method: str, path: str, *, timeout: float | None = None, **kwargs: Any
    ) -> tuple[Any, str | None]:
        if timeout is not None:
            kwargs["timeout"] = timeout
        try:
            async with self._http.stream(method, path, **kwargs) as answer:
                content = await _bounded(answer)
                following = answer.links.get("next", {}).get("url")
        except NOT_SENT as error:
            raise IaasUnreachable(
                self.base_url,
                f"cannot be reached ({_cause(error)})",
                maybe_delivered=False,
                timed_out=isinstance(error, httpx.TimeoutException),
            ) from None
        except httpx.TimeoutException:
            raise IaasUnreachable(
                self.base_url, "did not answer in time", maybe_delivered=True, timed_out=True
            ) from None
        except httpx.HTTPError as error:
            raise IaasUnreachable(
                self.base_url,
                f"broke off its answer ({_cause(error)})",
                maybe_delivered=True,
                timed_out=False,
            ) from None
        if content is None:
            raise _not_json(self.base_url, f"its answer is over {MAX_ANSWER_BYTES} bytes")
        if answer.status_code >= 400:
            sentence = _sentence(answer.status_code, answer.reason_phrase, content)
            if answer.status_code == 503 and answer.headers.get(Busy.HEADER) == "1":
                raise IaasBusy(sentence)
            raise IaasError(answer.status_code, sentence)
        try:
            return json.loads(content), following
        except ValueError:
            raise _not_json(self.base_url, "its answer is not JSON") from None


def checked_id(record_id: str, what: str = "request") -> str:
    if not REQUEST_ID.fullmatch(record_id):
        raise IaasError(404, f"there is no {what} {record_id[:80]!r}.")
    return record_id


class MissionEvents:
    """An open ``GET /v1/missions/{id}/events``: each ``event: mission`` as the mission."""

    def __init__(self, answer: httpx.Response, mission_id: str) -> None:
        self.answer = answer
        self.mission_id = mission_id

    async def missions(self) -> AsyncIterator[dict[str, Any]]:
        """The missions the stream sends, until it ends; what is not a mission is passed over."""
        name, size = "message", 0
        data: list[str] = []
        async for line in self.answer.aiter_lines():
            if line == "":
                if name == "mission" and data:
                    try:
                        mission = json.loads("\n".join(data))
                    except ValueError:
                        mission = None
                    if isinstance(mission, dict) and mission.get("id") == self.mission_id:
                        yield mission
                name, data, size = "message", [], 0
                continue
            field, _, value = line.partition(":")
            value = value.removeprefix(" ")
            if field == "event":
                name = value
            elif field == "data":
                size += len(value)
                if size > MAX_EVENT_BYTES:
                    raise _not_json(str(self.answer.url), f"an event is over {MAX_EVENT_BYTES} "
                                                          f"bytes")
                data.append(value)

    async def aclose(self) -> None:
        await self.answer.aclose()


def _not_json(url: str, what: str) -> IaasUnreachable:
    # An answer came, so the IaaS (or a proxy before it) may have acted.
    return IaasUnreachable(url, f"gave no usable answer: {what}", maybe_delivered=True,
                           timed_out=False)


def _object(value: Any, url: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise _not_json(url, "its answer is not a JSON object")
    return value


def _list(value: Any, url: str) -> list[Any]:
    if not isinstance(value, list):
        raise _not_json(url, "its answer is not a JSON list")
    return value


def _sentence(status: int, reason: str, content: bytes) -> str:
    try:
        detail = json.loads(content).get("detail")
    except (ValueError, AttributeError):
        detail = None
    if isinstance(detail, str) and detail:
        return detail[:1000]
    return f"the IaaS answered {status} {reason} without a reason."


async def _bounded(answer: httpx.Response) -> bytes | None:
    """The answer's body, or None past ``MAX_ANSWER_BYTES`` (read no further)."""
    body = bytearray()
    async for chunk in answer.aiter_bytes():
        body += chunk
        if len(body) > MAX_ANSWER_BYTES:
            return None
    return bytes(body)


def _cause(error: httpx.HTTPError) -> str:
    text = str(error).strip()
    return text or type(error).__name__
