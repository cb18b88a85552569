"""The missions' HTTP routes (MISSION_API.md): thin, they call ``MissionService``.

``mission_routes`` is handed the app's own dependencies (the application an
API key belongs to, the bearer scheme, the declared answers), so this module
does not import ``robocloud.iaas.app``, which includes it. No ``from
__future__ import annotations`` here: FastAPI reads the handlers' annotations,
which name that dependency, a local of ``mission_routes``.
"""

import asyncio
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Annotated, Any

from fastapi import APIRouter, Body, Depends, Header, Path, Query, Request, Response
from fastapi.sse import EventSourceResponse, ServerSentEvent

from robocloud.domain.mission_ids import MISSION_ID
from robocloud.domain.request import IDEMPOTENCY_KEY_PATTERN, IDEMPOTENCY_KEY_RULE
from robocloud.iaas.missions.book import MISSION_STATES
from robocloud.iaas.missions.models import MissionCreate, MissionList, MissionPublic, read_body
from robocloud.iaas.missions.service import MissionService

MissionId = Annotated[str, Path(description="a mission's id, e.g. mis-abcdefgh2345")]


def _inlined(schema: Any, defs: dict[str, Any]) -> Any:
    """``schema`` with its ``$defs`` references replaced by what they name (no cycles here)."""
    if isinstance(schema, dict):
        ref = schema.get("$ref")
        if isinstance(ref, str) and ref.startswith("#/$defs/"):
            return _inlined(defs[ref.removeprefix("#/$defs/")], defs)
        return {k: _inlined(v, defs) for k, v in schema.items() if k != "$defs"}
    if isinstance(schema, list):
        return [_inlined(v, defs) for v in schema]
    return schema


def mission_body_schema() -> dict[str, Any]:
    """The JSON Schema of a posted mission (``MissionCreate``), self-contained for the
    OpenAPI: the body is read by ``read_body``, which reads JSON numbers and arrays
    as this schema says (the planner's own models are strict)."""
    schema = MissionCreate.model_json_schema()
    inlined: dict[str, Any] = _inlined(schema, schema.get("$defs", {}))
    return inlined


async def missions_of(request: Request) -> MissionService:
    service: MissionService = request.app.state.cloud.missions
    return service


Missions = Annotated[MissionService, Depends(missions_of)]
# What a client (and a fuzzer) can do next with the mission a POST made.
MISSION_LINKS = {
    name: {"operationId": operation, "parameters": {"mission_id": "$response.body#/id"}}
    for name, operation in (
        ("GetMission", "get_mission"),
        ("CancelMission", "cancel_mission"),
        ("FollowMission", "mission_events"),
    )
}


def mission_routes(
    application_of: Callable[..., Awaitable[str]],
    secured: list[Any],
    answers: Callable[..., dict[int | str, Any]],
) -> APIRouter:
    """The /v1/missions routes; ``application_of``: the app's dependency for the caller."""
    router = APIRouter()

    @router.post(
        "/v1/missions",
        dependencies=secured,
        status_code=202,
        response_model=MissionPublic,
        tags=["missions"],
        operation_id="create_mission",
        responses={**answers(401, 413, 422), 202: {"links": MISSION_LINKS}},
        openapi_extra={
            "requestBody": {
                "required": True,
                "content": {"application/json": {"schema": mission_body_schema()}},
            }
        },
    )
    async def create_mission(
        missions: Missions,
        application: Annotated[str, Depends(application_of)],
        response: Response,
        body: Annotated[
            Any,
            Body(
                description="docs/model.md's mission (tasks, precedence, end, priority, "
                "max_time, min_battery, execution), plus label and time_limit (planning "
                "seconds, 0.5 to 60, default 5)"
            ),
        ],
        idempotency_key: Annotated[
            str | None,
            Header(
                max_length=200,
                pattern=IDEMPOTENCY_KEY_PATTERN,
                description="a retry with the same key and body returns the same mission; "
                f"{IDEMPOTENCY_KEY_RULE}",
            ),
        ] = None,
    ) -> MissionPublic:
        """Send a mission: planned over the federation's robots, then carried out."""
        mission = await missions.submit(application, read_body(body), idempotency_key)
        response.headers["Location"] = f"/v1/missions/{mission.id}"
        return mission

    @router.get(
        "/v1/missions",
        dependencies=secured,
        response_model=MissionList,
        tags=["missions"],
        operation_id="list_missions",
        responses=answers(401, 422),
    )
    async def list_missions(
        missions: Missions,
        application: Annotated[str, Depends(application_of)],
        state: Annotated[
            str | None,
            Query(
                pattern="^(" + "|".join(MISSION_STATES) + ")$",
                description="only missions in this state",
            ),
        ] = None,
        limit: Annotated[int, Query(ge=1, le=200)] = 50,
        before: Annotated[
            str | None,
            Query(pattern=MISSION_ID.pattern, description="the `next` cursor of the last page"),
        ] = None,
    ) -> MissionList:
        shown, cursor = await missions.page(application, state, limit, before)
        return MissionList(missions=shown, next=cursor)

    @router.get(
        "/v1/missions/{mission_id}",
        dependencies=secured,
        response_model=MissionPublic,
        tags=["missions"],
        operation_id="get_mission",
        responses=answers(401, 404),
    )
    async def get_mission(
        mission_id: MissionId,
        missions: Missions,
        application: Annotated[str, Depends(application_of)],
    ) -> MissionPublic:
        return await missions.get(application, mission_id)

    @router.delete(
        "/v1/missions/{mission_id}",
        dependencies=secured,
        response_model=MissionPublic,
        tags=["missions"],
        operation_id="cancel_mission",
        responses=answers(401, 404),
    )
    async def cancel_mission(
        mission_id: MissionId,
        missions: Missions,
        application: Annotated[str, Depends(application_of)],
    ) -> MissionPublic:
        """Cancel a mission (again: harmless): every robot of it is told to stop, and released."""
        return await missions.cancel(application, mission_id)

    async def existing_mission(
        mission_id: MissionId,
        missions: Missions,
        application: Annotated[str, Depends(application_of)],
    ) -> MissionPublic:
        """The application's mission, or 404 (as a dependency: before a stream starts)."""
        return await missions.get(application, mission_id)

    async def mission_updates(
        mission: Annotated[MissionPublic, Depends(existing_mission)], missions: Missions
    ) -> AsyncIterator[asyncio.Queue[MissionPublic | None]]:
        """The stream's queue in the mission feed, for as long as the response lasts
        (as for requests: ``robocloud.iaas.feed`` says why not in the stream)."""
        with missions.feed.subscribe(mission.id) as updates:
            yield updates

    @router.get(
        "/v1/missions/{mission_id}/events",
        dependencies=secured,
        response_class=EventSourceResponse,
        tags=["missions"],
        operation_id="mission_events",
        responses=answers(401, 404),
    )
    async def mission_events(
        mission: Annotated[MissionPublic, Depends(existing_mission)],
        missions: Missions,
        application: Annotated[str, Depends(application_of)],
        updates: Annotated[
            asyncio.Queue[MissionPublic | None], Depends(mission_updates, scope="request")
        ],
    ) -> AsyncIterator[ServerSentEvent]:
        """Server-sent events: the mission now, then after each change, until it is final."""
        async for now in missions.events(application, mission.id, updates):
            yield ServerSentEvent(event="mission", data=now.model_dump(mode="json"))

    return router
