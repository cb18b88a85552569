"""The IaaS's HTTP API as the wildfire server calls it: one client, its key attached.

The errors it raises, each carrying what the page needs to show::

    IaasError               the IaaS answered with an error: its status and its sentence
    └── IaasUnreachable     no answer at all (refused, timed out, not HTTP): 502

``robocloud.wildfire.app`` maps them to HTTP responses, in one place.
"""

from __future__ import annotations

import json
import re
from typing import Any

import httpx

# Request ids travel inside a path: anything else could walk to another route.
REQUEST_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,127}")
LIST_PARAMETERS = ("state", "limit", "before")
FEDERATION = {"scope": "federation"}


class IaasError(Exception):
    """The IaaS answered ``status``; ``detail`` is its sentence for the user."""

    def __init__(self, status: int, detail: str) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail


class IaasUnreachable(IaasError):
    def __init__(self, url: str, cause: str) -> None:
        super().__init__(502, f"the IaaS at {url} cannot be reached ({cause}).")
        self.url = url


class IaasClient:
    """Thin async calls to one IaaS; answers are JSON bytes or parsed JSON."""

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

    async def aclose(self) -> None:
        await self._http.aclose()

    async def health(self) -> Any:
        return json.loads(await self._call("GET", "/healthz"))

    async def robots(self) -> Any:
        return json.loads(await self.robots_raw())

    async def robots_raw(self) -> bytes:
        """Every robot the IaaS sees: its own and, in a federation, every live cloud's."""
        return await self._call("GET", "/v1/robots", params=FEDERATION)

    async def list_requests(self, params: dict[str, str]) -> bytes:
        kept = {k: v for k, v in params.items() if k in LIST_PARAMETERS}
        return await self._call("GET", "/v1/requests", params=kept)

    async def create_request(self, body: bytes, idempotency_key: str | None = None) -> bytes:
        headers = {"Content-Type": "application/json"}
        if idempotency_key:
            headers["Idempotency-Key"] = idempotency_key
        return await self._call("POST", "/v1/requests", content=body, headers=headers)

    async def get_request(self, request_id: str) -> bytes:
        return await self._call("GET", f"/v1/requests/{checked_id(request_id)}")

    async def cancel_request(self, request_id: str) -> bytes:
        return await self._call("POST", f"/v1/requests/{checked_id(request_id)}/cancel")

    async def _call(self, method: str, path: str, **kwargs: Any) -> bytes:
        try:
            answer = await self._http.request(method, path, **kwargs)
        except httpx.TimeoutException:
            raise IaasUnreachable(self.base_url, "it did not answer in time") from None
        except httpx.HTTPError as error:
            raise IaasUnreachable(self.base_url, _cause(error)) from None
        if answer.status_code >= 400:
            raise IaasError(answer.status_code, _sentence(answer))
        if not _is_json(answer.content):
            raise IaasUnreachable(self.base_url, "its answer is not JSON")
        return answer.content


def checked_id(request_id: str) -> str:
    if not REQUEST_ID.fullmatch(request_id):
        raise IaasError(404, f"there is no request {request_id[:80]!r}.")
    return request_id


def _sentence(answer: httpx.Response) -> str:
    try:
        detail = answer.json().get("detail")
    except (ValueError, AttributeError):
        detail = None
    if isinstance(detail, str) and detail:
        return detail
    return f"the IaaS answered {answer.status_code} {answer.reason_phrase} without a reason."


def _is_json(content: bytes) -> bool:
    try:
        json.loads(content)
    except ValueError:
        return False
    return True


def _cause(error: httpx.HTTPError) -> str:
    text = str(error).strip()
    return text or type(error).__name__
