"""The wildfire server: the page's files, its live stream, and a narrow API over the IaaSs.

The browser calls ``/api/...`` here; the server calls the IaaSs with the
application's key, so the key never reaches the page. Routes stay thin: the
live state comes from :class:`~robocloud.wildfire.live.LiveModel` (kept by
:class:`~robocloud.wildfire.feed.LiveFeed`), calls on the operator's behalf go
through :class:`~robocloud.wildfire.iaas_pool.IaasPool` (a task or a mission
checked first by ``checks.py``), and errors become
``{"detail": "a sentence"}`` in one place (:func:`_install_error_handlers`).

::

    GET  /                              the page
    GET  /static/...                    its scripts, styles and icon (no CDN)
    GET  /metrics                       Prometheus text format (docs/metrics.md)
    GET  /api/live                      server-sent events: a snapshot, then a delta a tick
    GET  /api/health                    each IaaS's health; 200 while any answers
    GET  /api/config                    the forest, the currency, the robots' time scale
    GET  /api/robots                    the fleet as last heard (``heard`` set when stale)
    GET  /api/capabilities              capabilities of the fleet, with idle counts
    GET  /api/clouds                    the clouds, their health and robot counts
    GET  /api/requests                  ?state=&limit=&before=, newest first, every IaaS
    POST /api/requests                  send a task (an Idempotency-Key makes retries safe)
    GET  /api/requests/{id}             a request's state, coalition, front, history
    POST /api/requests/{id}/cancel      cancel it
    GET  /api/missions                  ?state=&limit=&before=, newest first, every IaaS
    POST /api/missions                  send several fires as one mission (Idempotency-Key too)
    GET  /api/missions/{id}             a mission: its state, its plan, its progress
    DELETE /api/missions/{id}           cancel it
    GET  /api/missions/{id}/events      server-sent events: the mission, then after each change

A mission (docs/model.md, "A mission") is sent, kept and listed as a request
is, under the same checks and the same sentences; its events are the IaaS's
own stream, relayed event by event (``event: mission``) with a comment every
``KEEPALIVE_S`` while it is quiet, and closed when the IaaS closes it (the
mission is final) or the page goes.

A send that may have reached an IaaS without an answer coming back is 504 (or
502) with ``"delivery": "unknown"``: the page then says the request is not
confirmed yet and sends again with the same key until it knows. An IaaS too
busy to take it (503 with ``X-Robocloud-Busy``) stored nothing: the send goes to
the next IaaS, and when all are busy it is 503 with ``"delivery": "none"``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Annotated, Any

import httpx
from fastapi import APIRouter, Depends, FastAPI, Header, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response, StreamingResponse
from fastapi.staticfiles import StaticFiles
from starlette.datastructures import MutableHeaders
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.middleware.gzip import GZipMiddleware
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from robocloud.domain.request import IDEMPOTENCY_KEY_PATTERN, IDEMPOTENCY_KEY_RULE
from robocloud.wildfire.checks import check_mission, check_task
from robocloud.wildfire.config import WildfireSettings
from robocloud.wildfire.feed import LiveFeed, TooManyPages, event
from robocloud.wildfire.iaas_client import IaasBusy, IaasError, IaasUnreachable, MissionEvents
from robocloud.wildfire.iaas_pool import Endpoint, IaasPool
from robocloud.wildfire.live import LiveModel, dumps, one_line, request_summary
from robocloud.wildfire.metrics import WildfireMetrics

log = logging.getLogger(__name__)

STATIC = Path(__file__).parent / "static"
MAX_BODY_BYTES = 64 * 1024
IDEMPOTENCY_KEY = re.compile(IDEMPOTENCY_KEY_PATTERN)
DEFAULT_PAGE = 25
# A quiet mission stream says it is alive this often (proxies close silent ones).
KEEPALIVE_S = 15.0

# The page loads nothing from anywhere but this server.
SECURITY_HEADERS = {
    "Content-Security-Policy": (
        "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
        "connect-src 'self'; object-src 'none'; base-uri 'none'; form-action 'self'; "
        "frame-ancestors 'none'"
    ),
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "X-Frame-Options": "DENY",
}


def create_wildfire_app(
    settings: WildfireSettings,
    *,
    transport: httpx.AsyncBaseTransport | None = None,
    clock: Callable[[], float] = time.time,
) -> FastAPI:
    """The server for ``settings.iaas``; ``transport`` lets tests fake the IaaSs."""

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        pool = IaasPool(settings, transport)
        model = LiveModel(settings, clock())
        feed = LiveFeed(pool, model, clock)
        app.state.pool, app.state.model, app.state.feed = pool, model, feed
        metrics.watch(feed, pool)
        running = asyncio.ensure_future(feed.run())
        try:
            yield
        finally:
            running.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await running
            await pool.aclose()

    app = FastAPI(
        title="robocloud Wildfire Suppression Application",
        version="0.2.0",
        description="Place the fire, send a request to the IaaS, follow it, cancel it.",
        lifespan=lifespan,
        docs_url=None,
        redoc_url=None,
    )
    app.state.settings = settings
    app.state.mission_streams = set()
    metrics = app.state.metrics = WildfireMetrics()
    _install_error_handlers(app)
    # JSON and the page's files; the live stream compresses itself (feed.py).
    app.add_middleware(GZipMiddleware, minimum_size=1024)
    app.add_middleware(SecurityHeaders)
    app.include_router(_api())
    app.mount("/static", StaticFiles(directory=STATIC), name="static")

    @app.get("/", include_in_schema=False)
    async def page() -> FileResponse:
        metrics.page_loads.inc()
        return FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-cache"})

    @app.get("/metrics", include_in_schema=False)
    async def scrape(request: Request) -> Response:
        """Prometheus text format (docs/metrics.md); open, like the page this server serves."""
        body, content_type = metrics.exposition(request.headers.get("accept"))
        return Response(body, media_type=content_type, headers={"Cache-Control": "no-store"})

    return app


def pool_of(request: Request) -> IaasPool:
    pool: IaasPool = request.app.state.pool
    return pool


def model_of(request: Request) -> LiveModel:
    model: LiveModel = request.app.state.model
    return model


def metrics_of(request: Request) -> WildfireMetrics:
    metrics: WildfireMetrics = request.app.state.metrics
    return metrics


def feed_of(request: Request) -> LiveFeed:
    feed: LiveFeed = request.app.state.feed
    return feed


Pool = Annotated[IaasPool, Depends(pool_of)]
Model = Annotated[LiveModel, Depends(model_of)]
Feed = Annotated[LiveFeed, Depends(feed_of)]


def _with_home(record: dict[str, Any], endpoint: Endpoint) -> dict[str, Any]:
    """The record, saying which cloud's IaaS holds it."""
    return {**record, "held_by": endpoint.cloud}


def _api() -> APIRouter:
    router = APIRouter(prefix="/api")

    @router.get("/live")
    async def live(request: Request, feed: Feed) -> StreamingResponse:
        try:
            subscriber, first = feed.subscribe()
        except TooManyPages:
            raise IaasError(503, "too many pages follow this server; close one and "
                                 "reload.") from None
        metrics_of(request).live_connections.inc()
        compress = "gzip" in request.headers.get("accept-encoding", "")
        headers = {"Cache-Control": "no-store", "X-Accel-Buffering": "no"}
        if compress:
            headers["Content-Encoding"] = "gzip"
            headers["Vary"] = "Accept-Encoding"
        return StreamingResponse(feed.stream(subscriber, first, compress),
                                 media_type="text/event-stream", headers=headers)

    @router.get("/health")
    async def health(pool: Pool) -> JSONResponse:
        if all(e.ok is None for e in pool.endpoints):
            await pool.check_health()
        endpoints = [e.as_json() for e in pool.endpoints]
        if any(e.ok for e in pool.endpoints):
            return JSONResponse({"status": "ok", "endpoints": endpoints})
        return JSONResponse({"detail": "no IaaS answers: " + "; ".join(
            f"{e.url}: {e.error}" for e in pool.endpoints), "endpoints": endpoints},
            status_code=502)

    @router.get("/config")
    async def config(model: Model) -> dict[str, Any]:
        return model.config_json()

    @router.get("/robots")
    async def robots(model: Model) -> list[dict[str, Any]]:
        return model.robots_json(time.time())

    @router.get("/capabilities")
    async def capabilities(model: Model) -> list[dict[str, Any]]:
        return model.capability_offers(time.time())

    @router.get("/clouds")
    async def clouds(model: Model) -> list[dict[str, Any]]:
        return model.clouds_json()

    @router.get("/requests")
    async def list_requests(
        pool: Pool, state: str | None = None, limit: str = str(DEFAULT_PAGE),
        before: str | None = None,
    ) -> dict[str, Any]:
        page = await pool.list_requests(state or None, _limit(limit), before or None,
                                        pool.settings.timeout)
        return {
            "items": [request_summary(record, endpoint.cloud) for record, endpoint in
                      page["items"]],
            "next": page["next"],
            "missing": page["missing"],
        }

    @router.post("/requests", status_code=202)
    async def create_request(
        request: Request,
        pool: Pool,
        model: Model,
        idempotency_key: Annotated[str | None, Header()] = None,
    ) -> JSONResponse:
        record, endpoint = await _send(request, idempotency_key, "request", check_task,
                                       pool.create_request)
        model.ingest_request(record, endpoint.cloud, time.time())
        return JSONResponse(_with_home(record, endpoint), status_code=202)

    @router.get("/requests/{request_id}")
    async def get_request(request_id: str, pool: Pool, model: Model) -> dict[str, Any]:
        record, endpoint = await pool.get_request(request_id)
        model.ingest_request(record, endpoint.cloud, time.time())
        return _with_home(record, endpoint)

    @router.post("/requests/{request_id}/cancel")
    async def cancel_request(request_id: str, pool: Pool, model: Model) -> dict[str, Any]:
        record, endpoint = await pool.cancel_request(request_id)
        log.info("request %s canceled by the operator at %s.", one_line(request_id),
                 endpoint.name())
        model.ingest_request(record, endpoint.cloud, time.time())
        return _with_home(record, endpoint)

    @router.get("/missions")
    async def list_missions(
        pool: Pool, state: str | None = None, limit: str = str(DEFAULT_PAGE),
        before: str | None = None,
    ) -> dict[str, Any]:
        page = await pool.list_missions(state or None, _limit(limit), before or None,
                                        pool.settings.timeout)
        return {
            "items": [_with_home(record, endpoint) for record, endpoint in page["items"]],
            "next": page["next"],
            "missing": page["missing"],
        }

    @router.post("/missions", status_code=202)
    async def create_mission(
        request: Request,
        pool: Pool,
        idempotency_key: Annotated[str | None, Header()] = None,
    ) -> JSONResponse:
        record, endpoint = await _send(request, idempotency_key, "mission", check_mission,
                                       pool.create_mission)
        return JSONResponse(_with_home(record, endpoint), status_code=202)

    @router.get("/missions/{mission_id}")
    async def get_mission(mission_id: str, pool: Pool) -> dict[str, Any]:
        record, endpoint = await pool.get_mission(mission_id)
        return _with_home(record, endpoint)

    @router.delete("/missions/{mission_id}")
    async def cancel_mission(mission_id: str, pool: Pool) -> dict[str, Any]:
        record, endpoint = await pool.cancel_mission(mission_id)
        log.info("mission %s canceled by the operator at %s.", one_line(mission_id),
                 endpoint.name())
        return _with_home(record, endpoint)

    @router.get("/missions/{mission_id}/events")
    async def mission_events(mission_id: str, request: Request, pool: Pool
                             ) -> StreamingResponse:
        streams: set[object] = request.app.state.mission_streams
        if len(streams) >= pool.settings.max_live_pages:
            raise IaasError(503, "too many pages follow this server; close one and reload.")
        events = await pool.mission_events(mission_id)
        return StreamingResponse(_relay(events, streams), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})

    return router


def _limit(text: str) -> int:
    if not text.isdigit():
        raise IaasError(422, "limit must be a whole number from 1 to 200.")
    return int(text)


async def _send(
    request: Request, idempotency_key: str | None, what: str,
    check: Callable[[bytes, LiveModel], None],
    create: Callable[[bytes, str | None], Any],
) -> tuple[dict[str, Any], Endpoint]:
    """A request or a mission sent on the page's behalf: checked, counted, logged, pinned."""
    if idempotency_key is not None and not IDEMPOTENCY_KEY.fullmatch(idempotency_key):
        raise IaasError(422, f"the Idempotency-Key header must be {IDEMPOTENCY_KEY_RULE}.")
    metrics = metrics_of(request)
    sends = metrics.sends if what == "request" else metrics.mission_sends
    try:
        body = await _bounded_body(request, what)
        check(body, model_of(request))
        record, endpoint = await create(body, idempotency_key)
    except IaasUnreachable as error:
        sends.labels("unknown").inc()
        log.warning("a %s may not have reached the IaaS (the page sends it again): %s",
                    what, one_line(error.detail))
        raise
    except IaasError as error:
        sends.labels("refused" if error.status < 500 else "failed").inc()
        log.log(logging.INFO if error.status < 500 else logging.WARNING,
                "a %s was refused (%d): %s", what, error.status, one_line(error.detail))
        raise
    sends.labels("accepted").inc()
    log.info("%s %s sent to %s: %s.", what, one_line(str(record.get("id"))), endpoint.name(),
             one_line(str(record.get("state"))))
    return record, endpoint


async def _relay(events: MissionEvents, streams: set[object]) -> AsyncIterator[bytes]:
    """The IaaS's mission events for one page, with a comment while nothing changes."""
    queue: asyncio.Queue[bytes | None] = asyncio.Queue(8)

    async def read() -> None:
        try:
            async for mission in events.missions():
                await queue.put(event("mission", dumps(mission)))
        except (httpx.HTTPError, IaasError) as error:
            log.info("a mission's event stream broke off: %s", one_line(str(error)))
        finally:
            await queue.put(None)

    token = object()
    streams.add(token)
    reader = asyncio.ensure_future(read())
    try:
        yield b"retry: 3000\n\n"
        while True:
            try:
                data = await asyncio.wait_for(queue.get(), KEEPALIVE_S)
            except TimeoutError:
                yield b": keep-alive\n\n"
                continue
            if data is None:
                return
            yield data
    finally:
        streams.discard(token)
        reader.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await reader
        await events.aclose()


async def _bounded_body(request: Request, what: str) -> bytes:
    body = b""
    async for chunk in request.stream():
        body += chunk
        if len(body) > MAX_BODY_BYTES:
            raise IaasError(413, f"the body is over {MAX_BODY_BYTES} bytes, the most accepted.")
    if not body.strip():
        raise IaasError(422, f"the request body is missing: send a JSON "
                             f"{'task' if what == 'request' else what}.")
    return body


def _install_error_handlers(app: FastAPI) -> None:
    """The one place errors become responses: always ``{"detail": "a sentence"}``."""

    async def iaas_error(_: Request, error: Exception) -> JSONResponse:
        assert isinstance(error, IaasError)
        body: dict[str, Any] = {"detail": error.detail}
        if isinstance(error, IaasUnreachable):
            # Whether the IaaS may have acted: the page's truthful "not confirmed yet".
            body["delivery"] = "unknown" if error.maybe_delivered else "none"
        elif isinstance(error, IaasBusy):
            body["delivery"] = "none"  # every IaaS was too busy and stored nothing
        elif error.status >= 500:
            body["delivery"] = "unknown"
        return JSONResponse(body, status_code=error.status)

    async def http_error(_: Request, error: Exception) -> JSONResponse:
        assert isinstance(error, StarletteHTTPException)
        text = {404: "there is no such path.", 405: "this method is not allowed here."}.get(
            error.status_code, str(error.detail)
        )
        return JSONResponse({"detail": text}, status_code=error.status_code)

    async def validation_error(_: Request, error: Exception) -> JSONResponse:
        assert isinstance(error, RequestValidationError)
        where = ".".join(str(p) for p in (error.errors() or [{}])[0].get("loc", ()))
        return JSONResponse({"detail": f"{where or 'the request'} is not valid."},
                            status_code=422)

    async def unexpected(_: Request, error: Exception) -> JSONResponse:
        log.exception("unexpected error", exc_info=error)
        return JSONResponse(
            {"detail": "the wildfire server hit an internal error; it is logged."}, status_code=500
        )

    app.add_exception_handler(IaasError, iaas_error)
    app.add_exception_handler(StarletteHTTPException, http_error)
    app.add_exception_handler(RequestValidationError, validation_error)
    app.add_exception_handler(Exception, unexpected)


class SecurityHeaders:
    """Security headers on every answer, and no caching of the API's live answers.

    Plain ASGI rather than ``@app.middleware``: the live stream passes through
    untouched, event by event.
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        api = str(scope.get("path", "")).startswith("/api/")

        async def sending(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = MutableHeaders(scope=message)
                for name, value in SECURITY_HEADERS.items():
                    headers[name] = value
                if api:
                    headers["Cache-Control"] = "no-store"
            await send(message)

        await self.app(scope, receive, sending)
