"""The IaaS's HTTP API: thin routes over ``RequestService``, errors mapped in one place.

``create_app`` builds everything from ``Settings``; long-lived resources (the
store, the Zenoh router session, the robot link, the service) are opened and
closed in the app's lifespan. Tests may hand in a store and a link of their own.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Annotated, Any, Literal

from fastapi import Depends, FastAPI, Header, Query, Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.sse import EventSourceResponse, ServerSentEvent
from starlette.exceptions import HTTPException as StarletteHTTPException

from robocloud.domain import REQUEST_STATES
from robocloud.errors import (
    Conflict,
    InvalidInput,
    NotFound,
    PayloadTooLarge,
    RoboCloudError,
    Unauthorized,
    describe_validation_errors,
)
from robocloud.federation.messages import CloudInfo
from robocloud.federation.overlay import ZenohOverlay
from robocloud.federation.view import FederationView
from robocloud.fleet.link import RobotLink
from robocloud.iaas.config import Settings
from robocloud.iaas.home import Home, reconcile_period
from robocloud.iaas.models import (
    ErrorBody,
    Health,
    RequestCreate,
    RequestList,
    RequestPublic,
    RobotPublic,
)
from robocloud.iaas.presenters import remote_robot_public, request_public, robot_public
from robocloud.iaas.service import RequestService
from robocloud.storage import RequestStore, open_store

log = logging.getLogger(__name__)

# The one place user errors become HTTP status codes.
STATUS: dict[type[RoboCloudError], int] = {
    PayloadTooLarge: 413,
    InvalidInput: 422,
    NotFound: 404,
    Unauthorized: 401,
    Conflict: 409,
}


def status_of(error: RoboCloudError) -> int:
    for cls in type(error).__mro__:
        if cls in STATUS:
            return STATUS[cls]
    return 400


ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorBody, "description": text}
    for code, text in [
        (401, "missing or wrong API key"),
        (404, "no such request"),
        (409, "the request's state does not allow it"),
        (413, "the body is too large"),
        (422, "invalid input"),
    ]
}


def create_app(
    settings: Settings, store: RequestStore | None = None, link: RobotLink | None = None
) -> FastAPI:
    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        async with contextlib.AsyncExitStack() as stack:
            the_store = store
            if the_store is None:
                the_store = open_store(settings.store_url)
                stack.callback(the_store.close)
            the_link = link
            session = None
            if the_link is None:
                from robocloud.fleet import ZenohRobotLink, open_router

                security = settings.overlay_security
                session = open_router(
                    list(settings.zenoh_listen),
                    list(settings.zenoh_peers),
                    security.for_cloud(settings.cloud, settings.trusted) if security else None,
                )
                stack.callback(session.close)
                the_link = ZenohRobotLink(
                    session, settings.cloud, offline_after=settings.offline_after
                )
                stack.callback(the_link.close)
            home = Home(
                settings.cloud,
                the_store,
                the_link,
                settings.trusted,
                api=f"http://{settings.host}:{settings.port}",
                lease_max=settings.lease_max,
                origin_deadline=settings.origin_deadline,
            )
            overlay = None
            if session is not None and settings.federation:
                overlay = ZenohOverlay(
                    session, settings.cloud, home, offline_after=settings.offline_after
                )
                stack.callback(overlay.close)
                home.overlay = overlay
            view = FederationView(
                settings.cloud, the_store, the_link, overlay, settings.gather_timeout
            )
            home.lenders = view.lenders
            service = RequestService(settings, the_store, view)
            service.home_info = home.info
            home.origin = service
            await service.start()
            stack.push_async_callback(service.stop)
            reconciling = asyncio.ensure_future(
                home.reconcile_forever(reconcile_period(settings.origin_deadline))
            )
            stack.callback(reconciling.cancel)
            app.state.service = service
            app.state.overlay = overlay
            yield

    app = FastAPI(
        title=f"robocloud IaaS ({settings.cloud})",
        version="0.1.0",
        description="Send tasks to a federation of robot clouds; follow and cancel them.",
        lifespan=lifespan,
        responses=ERRORS,
    )
    app.state.settings = settings
    _install_error_handlers(app)
    _install_body_limit(app, settings.max_body_bytes)
    app.include_router(_routes())
    return app


def service_of(request: Request) -> RequestService:
    service: RequestService = request.app.state.service
    return service


def application_of(request: Request, authorization: Annotated[str | None, Header()] = None) -> str:
    """The application an API key belongs to (``Authorization: Bearer KEY``)."""
    keys = request.app.state.settings.api_keys
    scheme, _, key = (authorization or "").partition(" ")
    if not authorization:
        raise Unauthorized("an API key is required: send 'Authorization: Bearer <key>'.")
    if scheme.lower() != "bearer" or key.strip() not in keys:
        raise Unauthorized("the API key is not valid.")
    application: str = keys[key.strip()]
    return application


Service = Annotated[RequestService, Depends(service_of)]
Application = Annotated[str, Depends(application_of)]


def _routes() -> Any:
    from fastapi import APIRouter

    router = APIRouter()

    @router.get("/healthz", response_model=Health, tags=["service"])
    async def health(service: Service) -> Health:
        return Health(
            status="ok",
            cloud=service.settings.cloud,
            robots=len(service.link.robots()),
            store=service.settings.store_url.split(":", 1)[0],
            time_scale=service.settings.time_scale,
        )

    @router.post("/v1/requests", status_code=202, response_model=RequestPublic, tags=["requests"])
    async def create_request(
        body: RequestCreate,
        service: Service,
        application: Application,
        response: Response,
        idempotency_key: Annotated[str | None, Header(max_length=200)] = None,
    ) -> RequestPublic:
        """Send a task; robocloud selects, reserves and dispatches a coalition for it."""
        record = await service.submit(application, body.task(), body.label, idempotency_key)
        response.headers["Location"] = f"/v1/requests/{record.id}"
        return request_public(record, service)

    @router.get("/v1/requests", response_model=RequestList, tags=["requests"])
    async def list_requests(
        service: Service,
        application: Application,
        state: Annotated[str | None, Query(description="only requests in this state")] = None,
        limit: Annotated[int, Query(ge=1, le=200)] = 50,
        before: Annotated[
            str | None, Query(description="the `next` cursor of the previous page")
        ] = None,
    ) -> RequestList:
        if state is not None and state not in REQUEST_STATES:
            raise InvalidInput(
                f"state must be one of {', '.join(REQUEST_STATES)}; {state!r} is not a state.",
                "state",
            )
        records, cursor = await asyncio.to_thread(
            service.store.list, application, state, limit, before
        )
        return RequestList(items=[request_public(r, service) for r in records], next=cursor)

    @router.get("/v1/requests/{request_id}", response_model=RequestPublic, tags=["requests"])
    async def get_request(
        request_id: str, service: Service, application: Application
    ) -> RequestPublic:
        return request_public(await service.get(application, request_id), service)

    @router.post(
        "/v1/requests/{request_id}/cancel", response_model=RequestPublic, tags=["requests"]
    )
    async def cancel_request(
        request_id: str, service: Service, application: Application
    ) -> RequestPublic:
        """Cancel a request that is not finished: every robot stops and is released."""
        return request_public(await service.cancel(application, request_id), service)

    @router.get(
        "/v1/requests/{request_id}/events", response_class=EventSourceResponse, tags=["requests"]
    )
    async def request_events(
        request_id: str, service: Service, application: Application
    ) -> AsyncIterator[ServerSentEvent]:
        """Server-sent events: the request now, then after each change, until it is final."""
        await service.get(application, request_id)  # 404 before the stream starts
        async for record in service.events(application, request_id):
            yield ServerSentEvent(
                event="request", data=request_public(record, service).model_dump(mode="json")
            )

    @router.get("/v1/robots", response_model=list[RobotPublic], tags=["robots"])
    async def robots(
        request: Request,
        service: Service,
        application: Application,
        scope: Annotated[
            Literal["cloud", "federation"],
            Query(description="this cloud's robots, or those of every live cloud"),
        ] = "cloud",
    ) -> list[RobotPublic]:
        """The live state of the robots."""
        robots = robot_public(service)
        overlay: ZenohOverlay | None = request.app.state.overlay
        if scope == "federation" and overlay is not None:
            for fleet in await asyncio.to_thread(overlay.fleets):
                robots += [remote_robot_public(r) for r in fleet.robots]
        return robots

    @router.get("/v1/clouds", response_model=list[CloudInfo], tags=["federation"])
    async def clouds(
        request: Request, service: Service, application: Application
    ) -> list[CloudInfo]:
        """The live clouds of the federation (this one first) and their robot counts."""
        overlay: ZenohOverlay | None = request.app.state.overlay
        if overlay is None:
            return [service.home_info()]
        return await asyncio.to_thread(overlay.infos)

    return router


def _install_error_handlers(app: FastAPI) -> None:
    async def robocloud_error(_: Request, error: Exception) -> JSONResponse:
        assert isinstance(error, RoboCloudError)
        headers = {"WWW-Authenticate": "Bearer"} if isinstance(error, Unauthorized) else None
        return JSONResponse(
            {"detail": error.message}, status_code=status_of(error), headers=headers
        )

    async def validation_error(_: Request, error: Exception) -> JSONResponse:
        assert isinstance(error, RequestValidationError)
        errors = list(error.errors())
        # FastAPI prefixes the place ("body", "query", "header"); a body field
        # is named as in the task, the others by where they come from.
        for e in errors:
            loc = tuple(e.get("loc", ()))
            if loc[:1] == ("body",):
                e["loc"] = loc[1:]
        sentence = describe_validation_errors(errors).message
        if errors and errors[0].get("loc") == () and errors[0].get("type") == "missing":
            sentence = "the request body is missing: send a JSON task."
        return JSONResponse({"detail": sentence}, status_code=422)

    async def http_error(_: Request, error: Exception) -> JSONResponse:
        assert isinstance(error, StarletteHTTPException)
        text = {404: "there is no such path.", 405: "this method is not allowed here."}.get(
            error.status_code, str(error.detail)
        )
        return JSONResponse({"detail": text}, status_code=error.status_code)

    async def unexpected(_: Request, error: Exception) -> JSONResponse:
        log.exception("unexpected error", exc_info=error)
        return JSONResponse(
            {"detail": "the IaaS hit an internal error; it is logged."}, status_code=500
        )

    app.add_exception_handler(RoboCloudError, robocloud_error)
    app.add_exception_handler(RequestValidationError, validation_error)
    app.add_exception_handler(StarletteHTTPException, http_error)
    app.add_exception_handler(Exception, unexpected)


def _install_body_limit(app: FastAPI, limit: int) -> None:
    """413 for a body over ``limit`` bytes, before anything reads it whole."""

    @app.middleware("http")
    async def body_limit(
        request: Request, call_next: Callable[[Request], Awaitable[Response]]
    ) -> Response:
        length = request.headers.get("content-length")
        if length is not None and length.isdigit() and int(length) > limit:
            return JSONResponse(
                {"detail": f"the body is {int(length)} bytes; at most {limit} are accepted."},
                status_code=413,
            )
        if length is None and request.method in ("POST", "PUT", "PATCH"):
            body = b""
            async for chunk in request.stream():
                body += chunk
                if len(body) > limit:
                    return JSONResponse(
                        {"detail": f"the body is over {limit} bytes, the most accepted."},
                        status_code=413,
                    )
            request._body = body
        return await call_next(request)
