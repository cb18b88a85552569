"""The missions' wire shapes (MISSION_API.md, docs/model.md "A mission in the IaaS").

``MissionCreate`` is what an application posts: docs/model.md's ``mission``
object, plus ``label`` and ``time_limit`` (planning seconds). ``mission_json``
is what it reads back.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from robocloud.errors import InvalidInput, describe_validation_errors
from robocloud.iaas.missions.book import MissionRecord
from robocloud.iaas.missions.plans import NOT_STARTED
from robocloud.iaas.models import LABEL_PATTERN
from robocloud.planning.mission import Mission

DEFAULT_TIME_LIMIT = 5.0


class MissionCreate(Mission):
    """docs/model.md's mission, a label, and how long the planner may take."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    label: Annotated[str, Field(max_length=200, pattern=LABEL_PATTERN)] | None = None
    time_limit: Annotated[float, Field(ge=0.5, le=60.0, allow_inf_nan=False)] = Field(
        DEFAULT_TIME_LIMIT, description="seconds the planner may take (0.5 to 60)"
    )

    def mission(self) -> Mission:
        return Mission.model_validate(
            self.model_dump(exclude={"label", "time_limit"}), strict=False
        )


def read_body(body: Any) -> MissionCreate:
    """The posted body as a ``MissionCreate``, or a 422's sentence naming the field.

    JSON numbers are read as the schema says (an integer where a number is
    asked, a list where a pair is): the mission model itself is strict.
    """
    if not isinstance(body, dict):
        raise InvalidInput("the body must be a JSON object: a mission.", "body")
    try:
        return MissionCreate.model_validate(body, strict=False)
    except ValidationError as error:
        raise describe_validation_errors(error.errors()) from None


class MissionPublic(BaseModel):
    """A mission as GET /v1/missions/{id} answers it (MISSION_API.md)."""

    model_config = ConfigDict(extra="forbid")

    id: str
    label: str | None
    state: str = Field(
        description="planning, underway, completed; or rejected, failed, canceled (final)"
    )
    reason: str | None
    created_at: float
    updated_at: float
    started_at: float | None = Field(description="time 0 of the plan's times (unix seconds)")
    mission: dict[str, Any]
    plan: dict[str, Any] | None = Field(
        description="version, planned_at, makespan, lower_bound, gap, optimal, tasks, robots; "
        "times in robot seconds from started_at"
    )
    progress: float
    history: list[dict[str, Any]]


class MissionList(BaseModel):
    missions: list[MissionPublic]
    next: str | None = Field(description="the cursor of the next page (a mission id), or null")


def mission_json(record: MissionRecord) -> MissionPublic:
    plan: dict[str, Any] | None = None
    if record.plan is not None:
        by_number = record.tasks
        plan = {
            **record.plan,
            "tasks": [
                {
                    "id": run.id,
                    "location": list(run.location),
                    "robots": list(run.robots),
                    "start": run.start,
                    "end": run.end,
                    "state": run.state,
                    "progress": run.progress,
                }
                for run in by_number.values()
            ],
            "robots": [
                {
                    "id": member.id,
                    "cloud": member.cloud,
                    "from": list(member.origin),
                    "legs": [
                        {
                            "task": by_number[leg.task].id,
                            "depart": leg.depart,
                            "arrive": leg.arrive,
                            "start": leg.start,
                            "end": leg.end,
                        }
                        for leg in member.legs
                    ],
                    "end": None if record.mission.end is None else list(record.mission.end),
                    "home_at": member.home_at,
                    "state": member.state,
                }
                for member in record.robots.values()
            ],
        }
    return MissionPublic(
        id=record.id,
        label=record.label,
        state=record.state,
        reason=record.reason,
        created_at=record.created_at,
        updated_at=record.updated_at,
        started_at=record.started_at,
        mission=record.mission.model_dump(mode="json"),
        plan=plan,
        progress=progress_of(record),
        history=list(record.history),
    )


def progress_of(record: MissionRecord) -> float:
    """The share of the tasks' work done: each task counts by its progress."""
    if record.state == "completed":
        return 1.0
    runs = list(record.tasks.values())
    if not runs:
        return 0.0
    return sum(0.0 if r.state in NOT_STARTED else r.progress for r in runs) / len(runs)
