"""The wildfire server: the page's files and a narrow API over the IaaS.

The browser calls ``/api/...`` here; the server calls the IaaS with the
application's key, so the key never reaches the page. Routes stay thin: each
is one call of :class:`~robocloud.wildfire.iaas_client.IaasClient`, and the
IaaS's errors come back with its status and its sentence, mapped in one place
(:func:`_install_error_handlers`).

::

    GET  /                              the page
    GET  /static/...                    its scripts, styles and icon (no CDN)
    GET  /api/health                    the IaaS's /healthz
    GET  /api/robots                    every robot the IaaS sees, live
    GET  /api/capabilities              capabilities of the fleet, with idle counts
    GET  /api/clouds                    the clouds of the fleet, with robot counts
    GET  /api/requests                  ?state=&limit=&before=, newest first
    POST /api/requests                  send a task (MODEL.md's shape, plus a label)
    GET  /api/requests/{id}             a request's state, coalition, front, history
    POST /api/requests/{id}/cancel      cancel it
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Annotated, Any

import httpx
from fastapi import APIRouter, Depends, FastAPI, Header, Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException as StarletteHTTPException

from robocloud.wildfire.fleet_view import (
    CapabilityOffer,
    CloudSummary,
    capability_offers,
    cloud_summaries,
)
from robocloud.wildfire.iaas_client import IaasClient, IaasError

log = logging.getLogger(__name__)

STATIC = Path(__file__).parent / "static"
MAX_BODY_BYTES = 64 * 1024

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
    iaas_url: str,
    api_key: str | None,
    *,
    timeout: float = 10.0,
    transport: httpx.AsyncBaseTransport | None = None,
) -> FastAPI:
    """The server for the IaaS at ``iaas_url``; ``transport`` lets tests fake the IaaS."""

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        client = IaasClient(iaas_url, api_key, timeout=timeout, transport=transport)
        app.state.iaas = client
        try:
            yield
        finally:
            await client.aclose()

    app = FastAPI(
        title="robocloud Wildfire Suppression Application",
        version="0.1.0",
        description="Place the fire, send a request to the IaaS, follow it, cancel it.",
        lifespan=lifespan,
        docs_url=None,
        redoc_url=None,
    )
    _install_error_handlers(app)
    _install_headers(app)
    app.include_router(_api())
    app.mount("/static", StaticFiles(directory=STATIC), name="static")

    @app.get("/", include_in_schema=False)
    async def page() -> FileResponse:
        return FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-cache"})

    return app


def iaas_of(request: Request) -> IaasClient:
    client: IaasClient = request.app.state.iaas
    return client


Iaas = Annotated[IaasClient, Depends(iaas_of)]


def _json(content: bytes, status: int = 200) -> Response:
    return Response(content, status_code=status, media_type="application/json")


def _api() -> APIRouter:
    router = APIRouter(prefix="/api")

    @router.get("/health")
    async def health(iaas: Iaas) -> dict[str, Any]:
        return {"status": "ok", "iaas": await iaas.health()}

    @router.get("/robots")
    async def robots(iaas: Iaas) -> Response:
        return _json(await iaas.robots_raw())

    @router.get("/capabilities", response_model=list[CapabilityOffer])
    async def capabilities(iaas: Iaas) -> list[CapabilityOffer]:
        return capability_offers(_robot_list(await iaas.robots()))

    @router.get("/clouds", response_model=list[CloudSummary])
    async def clouds(iaas: Iaas) -> list[CloudSummary]:
        return cloud_summaries(_robot_list(await iaas.robots()))

    @router.get("/requests")
    async def list_requests(request: Request, iaas: Iaas) -> Response:
        return _json(await iaas.list_requests(dict(request.query_params)))

    @router.post("/requests", status_code=202)
    async def create_request(
        request: Request,
        iaas: Iaas,
        idempotency_key: Annotated[str | None, Header(max_length=200)] = None,
    ) -> Response:
        body = await _bounded_body(request)
        return _json(await iaas.create_request(body, idempotency_key), status=202)

    @router.get("/requests/{request_id}")
    async def get_request(request_id: str, iaas: Iaas) -> Response:
        return _json(await iaas.get_request(request_id))

    @router.post("/requests/{request_id}/cancel")
    async def cancel_request(request_id: str, iaas: Iaas) -> Response:
        return _json(await iaas.cancel_request(request_id))

    return router


def _robot_list(robots: Any) -> list[dict[str, Any]]:
    if not isinstance(robots, list):
        raise IaasError(502, "the IaaS's robot list is not a list.")
    return [r for r in robots if isinstance(r, dict)]


async def _bounded_body(request: Request) -> bytes:
    body = b""
    async for chunk in request.stream():
        body += chunk
        if len(body) > MAX_BODY_BYTES:
            raise IaasError(413, f"the body is over {MAX_BODY_BYTES} bytes, the most accepted.")
    if not body.strip():
        raise IaasError(422, "the request body is missing: send a JSON task.")
    return body


def _install_error_handlers(app: FastAPI) -> None:
    """The one place errors become responses: always ``{"detail": "a sentence"}``."""

    async def iaas_error(_: Request, error: Exception) -> JSONResponse:
        assert isinstance(error, IaasError)
        return JSONResponse({"detail": error.detail}, status_code=error.status)

    async def http_error(_: Request, error: Exception) -> JSONResponse:
        assert isinstance(error, StarletteHTTPException)
        text = {404: "there is no such path.", 405: "this method is not allowed here."}.get(
            error.status_code, str(error.detail)
        )
        return JSONResponse({"detail": text}, status_code=error.status_code)

    async def validation_error(_: Request, error: Exception) -> JSONResponse:
        # The only input FastAPI checks here is the Idempotency-Key header.
        return JSONResponse({"detail": "the Idempotency-Key header is too long."}, status_code=422)

    async def unexpected(_: Request, error: Exception) -> JSONResponse:
        log.exception("unexpected error", exc_info=error)
        return JSONResponse(
            {"detail": "the wildfire server hit an internal error; it is logged."}, status_code=500
        )

    app.add_exception_handler(IaasError, iaas_error)
    app.add_exception_handler(StarletteHTTPException, http_error)
    app.add_exception_handler(RequestValidationError, validation_error)
    app.add_exception_handler(Exception, unexpected)


def _install_headers(app: FastAPI) -> None:
    @app.middleware("http")
    async def headers(
        request: Request, call_next: Callable[[Request], Awaitable[Response]]
    ) -> Response:
        response = await call_next(request)
        response.headers.update(SECURITY_HEADERS)
        if request.url.path.startswith("/api/"):
            response.headers["Cache-Control"] = "no-store"
        return response
