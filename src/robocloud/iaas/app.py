"""The IaaS's HTTP API: thin routes over ``RequestService``, errors mapped in one place.

``create_app`` enters the composition root, ``build_cloud`` (``cloud.py``), in
the app's lifespan: the store, the Zenoh router session, the robot link, the
service and the rest are opened there and closed in reverse order. Tests may
hand in a store, a link and a selector of their own.

Why one long file: the routes, each with its OpenAPI declaration of the
answers it really gives, and the ``Gate`` they all pass; the parts behind
them are built in ``cloud.py``.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections.abc import AsyncIterator, Mapping
from typing import Annotated, Any, Literal
from urllib.parse import parse_qsl

from fastapi import Depends, FastAPI, Header, Path, Query, Request, Response, Security
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.utils import get_openapi
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute
from fastapi.security import HTTPBearer
from fastapi.sse import EventSourceResponse, ServerSentEvent
from starlette.datastructures import Headers
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.middleware.gzip import GZipMiddleware
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from robocloud.domain import RequestState
from robocloud.domain.request import IDEMPOTENCY_KEY_PATTERN, IDEMPOTENCY_KEY_RULE
from robocloud.domain.robot import NAME_PATTERN, Name, RobotStatus
from robocloud.errors import (
    Busy,
    Conflict,
    InvalidInput,
    NotFound,
    PayloadTooLarge,
    RoboCloudError,
    Unauthorized,
    Unavailable,
    describe_validation_errors,
)
from robocloud.federation.messages import CloudInfo
from robocloud.federation.overlay import ZenohOverlay
from robocloud.fleet.link import RobotLink
from robocloud.iaas.actor import Selector
from robocloud.iaas.capabilities import KnownCapabilities
from robocloud.iaas.cloud import build_cloud
from robocloud.iaas.config import Settings
from robocloud.iaas.docs_ui import install_docs
from robocloud.iaas.elsewhere import Elsewhere
from robocloud.iaas.feed import Updates
from robocloud.iaas.metrics import IaasMetrics, RouterRefusals
from robocloud.iaas.missions.api import mission_routes
from robocloud.iaas.models import (
    ErrorBody,
    Health,
    RequestCreate,
    RequestList,
    RequestPublic,
    RobotPublic,
)
from robocloud.iaas.presenters import request_public
from robocloud.iaas.protocol_routes import install_protocol
from robocloud.iaas.robot_list import (
    CURSOR_PATTERN,
    DEFAULT_LIMIT,
    MAX_LIMIT,
    PAGE_BYTES,
    RobotFilter,
    RobotJson,
    build_page,
    decode_cursor,
    etag_of,
    local_rows,
    matches,
    next_link,
    refused_rows,
    remote_rows,
)
from robocloud.iaas.service import REQUEST_ID, RequestService
from robocloud.json_body import repeated_key
from robocloud.storage import RequestRecord, RequestStore, StoreUnavailable

log = logging.getLogger(__name__)

# The one place user errors become HTTP status codes.
STATUS: dict[type[RoboCloudError], int] = {
    PayloadTooLarge: 413,
    InvalidInput: 422,
    NotFound: 404,
    Unauthorized: 401,
    Conflict: 409,
    Unavailable: 503,
}


def status_of(error: RoboCloudError) -> int:
    for cls in type(error).__mro__:
        if cls in STATUS:
            return STATUS[cls]
    return 400


_ANSWERS = {
    401: "missing or wrong API key",
    404: "no such request",
    409: "the request's state does not allow it",
    413: "the body is too large",
    422: "invalid input (the sentence names the field)",
    503: "the store is unavailable, or (a new request) the cloud is busy; try again after "
    "Retry-After seconds",
}


def answers(*codes: int) -> dict[int | str, dict[str, Any]]:
    """The error answers an operation really gives, for its OpenAPI entry."""
    return {code: {"model": ErrorBody, "description": _ANSWERS[code]} for code in codes}


def create_app(
    settings: Settings,
    store: RequestStore | None = None,
    link: RobotLink | None = None,
    selector: Selector | None = None,
    router_refusals: RouterRefusals | None = None,
) -> FastAPI:
    """The IaaS's HTTP API over the parts ``build_cloud`` makes (in the lifespan).

    ``store``, ``link`` and ``selector`` replace the real ones (for tests).
    ``router_refusals``: where the metrics read what the router refused, when
    the command reads its trace (``router_refusals.watch``).
    """
    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        async with build_cloud(settings, metrics, store, link, selector) as cloud:
            app.state.cloud = cloud
            app.state.service = cloud.service
            app.state.overlay = cloud.overlay
            app.state.capabilities = cloud.capabilities
            app.state.elsewhere = cloud.elsewhere
            yield

    app = FastAPI(
        title=f"robocloud IaaS ({settings.cloud})",
        version="0.1.0",
        description="Send tasks to a federation of robot clouds; follow and cancel them.",
        lifespan=lifespan,
        docs_url=None,
        redoc_url=None,  # Swagger UI without a CDN: iaas/docs_ui.py
        # The IaaS has its own metrics (/metrics) and no OpenTelemetry: FastAPI's
        # checks for a configured provider cost every request a few lookups.
        telemetry={"tracing": False, "metrics": False, "logs": False, "operation_spans": False},
    )
    app.state.settings = settings
    metrics = app.state.metrics = IaasMetrics()
    if router_refusals is not None:
        metrics.observe_router(router_refusals)
    _install_error_handlers(app)
    # JSON answers of 1 KiB and more, gzipped for clients that accept it (a page
    # of 1,000 robots: 284 kB -> 23 kB). Starlette passes event streams
    # (text/event-stream) through untouched, event by event. Level 5: most of
    # level 9's gain for a third of its CPU.
    app.add_middleware(GZipMiddleware, minimum_size=1024, compresslevel=5)
    # The Gate last, so outermost: what it refuses (401, 413, a busy 503) is
    # answered before any other middleware runs.
    app.add_middleware(Gate, keys=settings.api_keys, limit=settings.max_body_bytes)
    routes = _routes()
    app.include_router(routes)
    missions = mission_routes(application_of, SECURED, answers)
    app.include_router(missions)
    app.openapi = lambda: _openapi(app)  # type: ignore[method-assign]
    install_docs(app)
    install_protocol(app)
    # Every route, for Allow and the OpenAPI's answers (those of included
    # routers are not in app.routes as routes of their own).
    app.state.routes = [
        r
        for r in (*routes.routes, *missions.routes, *app.router.routes)
        if isinstance(r, APIRoute)
    ]
    return app


def _openapi(app: FastAPI) -> dict[str, Any]:
    """FastAPI's OpenAPI, with only the answers each operation really gives.

    FastAPI adds a 422 (in its own error shape) to every operation with a
    parameter; here each operation lists the codes it declares (``answers``)
    and its success, and every error is an ``ErrorBody``.
    """
    if app.openapi_schema is None:
        spec = get_openapi(
            title=app.title,
            version=app.version,
            description=app.description,
            routes=app.routes,
        )
        routes: list[APIRoute] = app.state.routes
        error_body = {"application/json": {"schema": {"$ref": "#/components/schemas/ErrorBody"}}}
        for route in routes:
            success = str(route.status_code or 200)
            for method in route.methods or ():
                operation = spec["paths"].get(route.path_format, {}).get(method.lower())
                if operation is None:
                    continue
                declared = {str(code) for code in route.responses} | {success}
                operation["responses"] = {
                    code: answer
                    for code, answer in operation["responses"].items()
                    if code in declared
                }
                for code, answer in operation["responses"].items():
                    if int(code) >= 400:  # errors are JSON, even beside an event stream
                        answer["content"] = error_body
        schemas = spec.get("components", {}).get("schemas", {})
        for unused in ("HTTPValidationError", "ValidationError"):
            if f"#/components/schemas/{unused}" not in json.dumps(spec["paths"]):
                schemas.pop(unused, None)
        app.openapi_schema = spec
    return app.openapi_schema


async def service_of(request: Request) -> RequestService:
    service: RequestService = request.app.state.service
    return service


async def application_of(request: Request) -> str:
    """The application whose API key the ``Gate`` checked, before anything read the body."""
    application = request.scope.get("state", {}).get("application")
    if not isinstance(application, str):
        raise Unauthorized("an API key is required: send 'Authorization: Bearer <key>'.")
    return application


def authenticate(authorization: str | None, keys: Mapping[str, str]) -> str:
    """The application an API key belongs to (``Authorization: Bearer KEY``)."""
    if not authorization:
        raise Unauthorized("an API key is required: send 'Authorization: Bearer <key>'.")
    scheme, _, key = authorization.partition(" ")
    if scheme.lower() != "bearer" or key.strip() not in keys:
        raise Unauthorized("the API key is not valid.")
    return keys[key.strip()]


# Declares the scheme in the OpenAPI; the Gate does the checking.
BEARER = HTTPBearer(auto_error=False, description="the application's API key")
SECURED = [Security(BEARER)]
# What a client (and a fuzzer) can do next with the request a POST made.
REQUEST_LINKS = {
    name: {"operationId": operation, "parameters": {"request_id": "$response.body#/id"}}
    for name, operation in (
        ("GetRequest", "get_request"),
        ("CancelRequest", "cancel_request"),
        ("FollowRequest", "request_events"),
    )
}
ROBOT_PAGE_HEADERS = {
    "ETag": {
        "description": "weak validator of the page (seen_ago left out), for If-None-Match",
        "schema": {"type": "string"},
    },
    "Link": {
        "description": 'the next page, `<...>; rel="next"`, while more robots follow',
        "schema": {"type": "string"},
    },
    "X-Total-Count": {
        "description": "robots matching the filters, over every page",
        "schema": {"type": "integer"},
    },
}
RequestId = Annotated[str, Path(description="a request's id, e.g. req-abcdefgh2345")]


async def capabilities_of(request: Request) -> KnownCapabilities:
    known: KnownCapabilities = request.app.state.capabilities
    return known


async def elsewhere_of(request: Request) -> Elsewhere:
    elsewhere: Elsewhere = request.app.state.elsewhere
    return elsewhere


Service = Annotated[RequestService, Depends(service_of)]
Application = Annotated[str, Depends(application_of)]
Capabilities = Annotated[KnownCapabilities, Depends(capabilities_of)]
Federation = Annotated[Elsewhere, Depends(elsewhere_of)]


async def existing_request(
    request_id: RequestId, service: Service, application: Application, federation: Federation
) -> RequestRecord:
    """The application's request, or 404 (as a dependency: before a stream starts)."""
    return await federation.here(service.get(application, request_id), request_id)


OwnedRequest = Annotated[RequestRecord, Depends(existing_request)]


async def request_updates(record: OwnedRequest, service: Service) -> AsyncIterator[Updates]:
    """The stream's queue in the request feed, for as long as the response lasts.

    A dependency with ``yield``: FastAPI ends it when the response ends, the
    client gone included (``robocloud.iaas.feed`` says why not in the stream).
    """
    with service.feed.subscribe(record.id) as updates:
        yield updates


RequestUpdates = Annotated[Updates, Depends(request_updates, scope="request")]


def _routes() -> Any:
    from fastapi import APIRouter

    router = APIRouter()
    robot_json_cache = RobotJson()  # the robots' JSON, for GET /v1/robots
    api = router  # the /v1 routes declare the bearer scheme one by one (SECURED)

    @router.get("/healthz", response_model=Health, tags=["service"], operation_id="health")
    async def health(service: Service) -> Health:
        return Health(
            status="ok",
            cloud=service.settings.cloud,
            robots=len(service.link.robots()),
            store=service.settings.store_url.split(":", 1)[0],
            time_scale=service.settings.time_scale,
        )

    @router.get("/metrics", include_in_schema=False)
    async def metrics(request: Request, application: Application) -> Response:
        """The IaaS's metrics in the Prometheus text format (docs/metrics.md).

        Out of the OpenAPI: it is the operator's, not an application's. It asks
        for an API key like ``/v1/`` (the ``Gate``): Prometheus sends one with
        ``authorization: {credentials: KEY}`` in its scrape config.
        """
        the_metrics: IaasMetrics = request.app.state.metrics
        body, content_type = await asyncio.to_thread(
            the_metrics.exposition, request.headers.get("accept")
        )
        return Response(body, media_type=content_type, headers={"Cache-Control": "no-store"})

    @api.post(
        "/v1/requests",
        dependencies=SECURED,
        status_code=202,
        response_model=RequestPublic,
        tags=["requests"],
        operation_id="create_request",
        responses={**answers(401, 413, 422, 503), 202: {"links": REQUEST_LINKS}},
    )
    async def create_request(
        body: RequestCreate,
        service: Service,
        application: Application,
        known: Capabilities,
        response: Response,
        idempotency_key: Annotated[
            str | None,
            Header(
                max_length=200,
                pattern=IDEMPOTENCY_KEY_PATTERN,
                description="a retry with the same key and body returns the same request; "
                f"{IDEMPOTENCY_KEY_RULE}",
            ),
        ] = None,
    ) -> RequestPublic:
        """Send a task; robocloud selects, reserves and dispatches a coalition for it."""
        await known.check(body)
        record = await service.submit(application, body.task(), body.label, idempotency_key)
        response.headers["Location"] = f"/v1/requests/{record.id}"
        return request_public(record, service)

    @api.get(
        "/v1/requests",
        dependencies=SECURED,
        response_model=RequestList,
        operation_id="list_requests",
        tags=["requests"],
        responses=answers(401, 422, 503),
    )
    async def list_requests(
        service: Service,
        application: Application,
        state: Annotated[
            RequestState | None, Query(description="only requests in this state")
        ] = None,
        limit: Annotated[int, Query(ge=1, le=200)] = 50,
        before: Annotated[
            str | None,
            Query(
                pattern=REQUEST_ID.pattern,
                description="the `next` cursor of the previous page (a request id)",
            ),
        ] = None,
    ) -> RequestList:
        records, cursor = await service.in_store(
            service.store.list, application, state, limit, before
        )
        return RequestList(items=[request_public(r, service) for r in records], next=cursor)

    @api.get(
        "/v1/requests/{request_id}",
        dependencies=SECURED,
        operation_id="get_request",
        response_model=RequestPublic,
        tags=["requests"],
        responses=answers(401, 404, 503),
    )
    async def get_request(
        request_id: RequestId, service: Service, application: Application, federation: Federation
    ) -> RequestPublic:
        record = await federation.here(service.get(application, request_id), request_id)
        return request_public(record, service)

    @api.post(
        "/v1/requests/{request_id}/cancel",
        dependencies=SECURED,
        operation_id="cancel_request",
        response_model=RequestPublic,
        tags=["requests"],
        responses=answers(401, 404, 409, 503),
    )
    async def cancel_request(
        request_id: RequestId, service: Service, application: Application, federation: Federation
    ) -> RequestPublic:
        """Cancel a request that is not finished: every robot stops and is released."""
        record = await federation.here(service.cancel(application, request_id), request_id)
        return request_public(record, service)

    @api.get(
        "/v1/requests/{request_id}/events",
        dependencies=SECURED,
        operation_id="request_events",
        response_class=EventSourceResponse,
        tags=["requests"],
        responses=answers(401, 404, 503),
    )
    async def request_events(
        record: OwnedRequest,
        service: Service,
        application: Application,
        updates: RequestUpdates,
    ) -> AsyncIterator[ServerSentEvent]:
        """Server-sent events: the request now, then after each change, until it is final."""
        # The dependency answered 404 for an unknown request before the stream started.
        async for update in service.events(application, record.id, updates):
            yield ServerSentEvent(
                event="request", data=request_public(update, service).model_dump(mode="json")
            )

    @api.get(
        "/v1/robots",
        dependencies=SECURED,
        operation_id="list_robots",
        response_model=list[RobotPublic],
        tags=["robots"],
        responses={
            200: {"headers": ROBOT_PAGE_HEADERS},
            304: {
                "description": "Not Modified: the page is as the ETag sent in If-None-Match "
                "says (no body)",
                "headers": {"ETag": ROBOT_PAGE_HEADERS["ETag"]},
            },
            **answers(401, 422),
        },
    )
    async def robots(
        request: Request,
        service: Service,
        application: Application,
        scope: Annotated[
            Literal["cloud", "federation"],
            Query(description="this cloud's robots, or those of every live cloud"),
        ] = "cloud",
        status: Annotated[
            RobotStatus | None, Query(description="only robots in this status")
        ] = None,
        capability: Annotated[
            list[Name] | None,
            Query(
                max_length=20,
                description="only robots with this capability (repeat it: robots with all)",
            ),
        ] = None,
        cloud: Annotated[
            str | None,
            Query(
                min_length=1,
                max_length=128,
                pattern=NAME_PATTERN,
                description="only robots of this cloud (with scope=federation, any live one)",
            ),
        ] = None,
        limit: Annotated[
            int,
            Query(
                ge=1,
                le=MAX_LIMIT,
                description=f"robots a page ({DEFAULT_LIMIT} unless said, at most {MAX_LIMIT}); "
                f"a page also stops at the robot that takes it past {PAGE_BYTES} bytes of "
                "JSON; the Link header (rel=next) names the next page",
            ),
        ] = DEFAULT_LIMIT,
        cursor: Annotated[
            str | None,
            Query(
                pattern=CURSOR_PATTERN,
                description="where the page starts: the cursor of the previous page's "
                "Link (rel=next); opaque",
            ),
        ] = None,
        if_none_match: Annotated[
            str | None,
            Header(
                max_length=1000,
                description="the ETag of a page read before: 304 and no body if it is unchanged",
            ),
        ] = None,
    ) -> Response:
        """The live state of the robots, a page at a time (by cloud, then id).

        The body is a list of robots; the ``Link`` header (``rel="next"``) leads to
        the next page while more follow, ``X-Total-Count`` says how many robots
        match the filters, and the weak ``ETag`` (which leaves ``seen_ago`` out)
        answers ``If-None-Match`` with 304. A robot silent for longer than the
        IaaS's forget time (``--forget-after``, 10 minutes by default) is no longer
        listed; it is listed again when it reports.
        """
        after = decode_cursor(cursor) if cursor is not None else None
        wanted = RobotFilter(status, tuple(capability or ()), cloud)

        def owns(request_id: str) -> bool:  # only its owner sees a request id and progress
            return service.owner_of(request_id) == application

        link = service.link
        try:
            held = service.store.reservations()
        except StoreUnavailable:
            service.store_failed(service.store.reservations)
            raise
        local = local_rows(link.robots(), held, wanted)
        states = link.states()
        refused = link.refused()  # robots whose states are refused, with the reason
        remote: list[tuple[tuple[str, str], dict[str, Any]]] = []
        if refused and (cloud is None or cloud == service.settings.cloud):
            remote = refused_rows(service.settings.cloud, refused, states, wanted)
        overlay: ZenohOverlay | None = request.app.state.overlay
        if scope == "federation" and overlay is not None and cloud != service.settings.cloud:
            fleets = await asyncio.to_thread(overlay.fleets)
            remote += remote_rows(
                (f.robots for f in fleets), wanted, service.settings.cloud, owns
            )
        page = build_page(
            local,
            remote,
            after,
            limit,
            states,
            link.ages(),
            held,
            robot_json_cache,
            service.routes.aside,
            owns,
            refused=refused,
        )
        etag = etag_of(page)
        headers = {
            "ETag": etag,
            "Cache-Control": "private, no-cache",
            "X-Total-Count": str(page.total),
        }
        if page.next is not None:
            headers["Link"] = next_link(
                request.url.path, list(request.query_params.multi_items()), page.next
            )
        if matches(if_none_match, etag):
            return Response(status_code=304, headers=headers)
        return Response(page.body(), media_type="application/json", headers=headers)

    @api.get(
        "/v1/clouds",
        dependencies=SECURED,
        operation_id="list_clouds",
        response_model=list[CloudInfo],
        tags=["federation"],
        responses=answers(401),
    )
    async def clouds(
        request: Request, service: Service, application: Application
    ) -> list[CloudInfo]:
        """The live clouds of the federation (this one first) and their robot counts."""
        overlay: ZenohOverlay | None = request.app.state.overlay
        if overlay is None:
            return [service.home_info()]
        return await asyncio.to_thread(overlay.infos)

    return router


def allowed_methods(request: Request) -> list[str]:
    routes: list[APIRoute] = request.app.state.routes
    methods: set[str] = set()
    for route in routes:
        if route.path_regex.match(request.url.path):
            methods |= route.methods or set()
    return sorted(methods)


# Pydantic's error types for a body that is no object at all (a list, text).
NOT_AN_OBJECT = frozenset({"model_attributes_type", "model_type", "dict_type"})


def _media_type(headers: Headers) -> str:
    return headers.get("content-type", "").split(";", 1)[0].strip().lower()


def _says_json(request: Request) -> bool:
    """Whether the request's Content-Type is JSON (``application/json`` or ``+json``)."""
    media = _media_type(request.headers)
    return media == "application/json" or media.endswith("+json")


def _json_body(headers: Headers) -> bool:
    """Whether FastAPI reads the body as JSON: its Content-Type says so, or there is none."""
    media = _media_type(headers)
    return not media or media == "application/json" or media.endswith("+json")


def _install_error_handlers(app: FastAPI) -> None:
    async def robocloud_error(_: Request, error: Exception) -> JSONResponse:
        assert isinstance(error, RoboCloudError)
        return _error(error)

    async def validation_error(request: Request, error: Exception) -> JSONResponse:
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
        elif errors and errors[0].get("loc") == () and errors[0].get("type") in NOT_AN_OBJECT:
            # FastAPI reads a body as JSON only when its Content-Type says so.
            sentence = (
                "the body must be a JSON object: a task."
                if _says_json(request)
                else "the body is not JSON: send the task with Content-Type: application/json."
            )
        return JSONResponse({"detail": sentence}, status_code=422)

    async def http_error(request: Request, error: Exception) -> JSONResponse:
        assert isinstance(error, StarletteHTTPException)
        text = {404: "there is no such path.", 405: "this method is not allowed here."}.get(
            error.status_code, str(error.detail)
        )
        headers = dict(error.headers or {})
        if error.status_code == 400:
            # FastAPI's answer to a body it cannot decode (not UTF-8, say).
            return JSONResponse(
                {"detail": "the body could not be read as JSON (not UTF-8, or nested too "
                 "deep): send a JSON task in UTF-8."},
                status_code=422,
            )
        if error.status_code == 405:
            # Allow names every method of the path, as HTTP asks (Starlette
            # names those of the first route that matched the path only).
            headers["Allow"] = ", ".join(allowed_methods(request))
        return JSONResponse({"detail": text}, status_code=error.status_code, headers=headers)

    async def unexpected(_: Request, error: Exception) -> JSONResponse:
        log.exception("unexpected error", exc_info=error)
        return JSONResponse(
            {"detail": "the IaaS hit an internal error; it is logged."}, status_code=500
        )

    app.add_exception_handler(RoboCloudError, robocloud_error)
    app.add_exception_handler(RequestValidationError, validation_error)
    app.add_exception_handler(StarletteHTTPException, http_error)
    app.add_exception_handler(Exception, unexpected)


class Gate:
    """Checks what needs no body first: the API key on ``/v1/`` and ``/metrics`` (401), then the
    body's size (413), then a JSON body's repeated keys (422, ``robocloud.json_body``).

    A pure ASGI middleware, so a request without a key is refused before its
    body is read or parsed, and a body without a length is read at most
    ``limit`` bytes far.
    """

    def __init__(self, app: ASGIApp, keys: Mapping[str, str], limit: int) -> None:
        self.app = app
        self.keys = keys
        self.limit = limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        if scope["path"].startswith("/v1/") or scope["path"] == "/metrics":
            try:
                application = authenticate(headers.get("authorization"), self.keys)
            except Unauthorized as error:
                await _error(error)(scope, receive, send)
                return
            scope.setdefault("state", {})["application"] = application
            repeated = repeated_query_parameter(scope.get("query_string", b""))
            if repeated is not None:
                await _error(repeated)(scope, receive, send)
                return
            if (
                scope["method"] == "POST"
                and scope["path"] == "/v1/requests"
                and "idempotency-key" not in headers
            ):
                # A busy cloud refuses before the body is read: a refusal costs
                # little of the CPU it is short of. With an Idempotency-Key the
                # request may be a retry of one stored: ``submit`` decides.
                service: RequestService | None = getattr(scope["app"].state, "service", None)
                try:
                    if service is not None:
                        service.admission.admit()
                except Busy as busy:
                    await _error(busy)(scope, receive, send)
                    return
        length = headers.get("content-length")
        if length is not None and length.isdigit() and int(length) > self.limit:
            refusal = PayloadTooLarge(
                f"the body is {int(length)} bytes; at most {self.limit} are accepted."
            )
            await _error(refusal)(scope, receive, send)
            return
        if scope["method"] in ("POST", "PUT", "PATCH"):
            body = b""
            more = True
            while more:
                message = await receive()
                if message["type"] != "http.request":
                    return  # the client went away
                body += message.get("body", b"")
                more = message.get("more_body", False)
                if len(body) > self.limit:
                    refusal = PayloadTooLarge(
                        f"the body is over {self.limit} bytes, the most accepted."
                    )
                    await _error(refusal)(scope, receive, send)
                    return
            # Every JSON body of every route: a repeated key is a 422 naming it.
            repeated = repeated_key(body) if body and _json_body(headers) else None
            if repeated is not None:
                await _error(repeated)(scope, receive, send)
                return
            receive = _replay(body, receive)
        await self.app(scope, receive, send)


# Query parameters of the API that take several values (GET /v1/robots?capability=a&capability=b).
REPEATABLE_QUERY = frozenset({"capability"})


def repeated_query_parameter(query: bytes) -> InvalidInput | None:
    """A 422 for a single-valued query parameter given more than once, else None.

    FastAPI would silently keep the last value; the API says which one it saw twice.
    """
    seen: set[str] = set()
    for name, _ in parse_qsl(query.decode("latin-1"), keep_blank_values=True):
        if name in seen and name not in REPEATABLE_QUERY:
            return InvalidInput(
                f"the query parameter {name!r} is given more than once; give it once.",
                field=name,
            )
        seen.add(name)
    return None


def _replay(body: bytes, receive: Receive) -> Receive:
    sent = False

    async def replayed() -> Message:
        nonlocal sent
        if not sent:
            sent = True
            return {"type": "http.request", "body": body, "more_body": False}
        return await receive()

    return replayed


def _error(error: RoboCloudError) -> JSONResponse:
    """The one shape of an error answer: ``{"detail": sentence}`` and the headers it needs."""
    headers: dict[str, str] = {}
    if isinstance(error, Unauthorized):
        headers["WWW-Authenticate"] = "Bearer"
    if isinstance(error, Unavailable):
        headers["Retry-After"] = str(max(1, round(error.retry_after)))
    if isinstance(error, Busy):
        headers[Busy.HEADER] = "1"  # nothing stored: another cloud may take it at once
    return JSONResponse({"detail": error.message}, status_code=status_of(error), headers=headers)
