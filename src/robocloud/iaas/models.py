"""The HTTP API's wire models: what applications send and receive.

Stored rows are ``robocloud.storage`` records; these are the shapes on the
wire, named after what they carry (``RequestCreate`` in, ``RequestPublic`` out).
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from robocloud.domain import RequestState, Task
from robocloud.errors import explained

# A label is free text of one or more lines: no NUL (PostgreSQL refuses it)
# and no other control character but tab and newline.
LABEL_PATTERN = explained(
    r"^[^\x00-\x08\x0b\x0c\x0e-\x1f\x7f]*$",
    "text without control characters (tab and newline are allowed)",
)


class RequestCreate(Task):
    """A docs/model.md task, plus an optional label for the application's own use."""

    label: Annotated[str, Field(max_length=200, pattern=LABEL_PATTERN)] | None = None

    def task(self) -> Task:
        return Task.model_validate(self.model_dump(exclude={"label"}))


class Progress(BaseModel):
    phase: Literal["pending", "travel", "work", "done", "failed", "canceled"]
    progress: float = Field(ge=0.0, le=1.0)


class Assignment(BaseModel):
    """One robot of the chosen coalition."""

    robot: str
    cloud: str
    capabilities: list[str]
    time: float = Field(description="t_i: robot seconds it needs from when it was sent")
    cost: float = Field(description="c_i")
    offset: float = Field(
        0.0, description="robot seconds after the request's dispatch at which it was sent"
    )
    progress: Progress | None = None


class FrontMember(BaseModel):
    robots: list[str]
    time: float
    cost: float
    size: int


class HistoryEntry(BaseModel):
    kind: Literal["state", "event"]
    state: RequestState
    at: datetime
    detail: str | None = None


class RequestPublic(BaseModel):
    model_config = ConfigDict(json_schema_extra={"description": "A request and its state."})

    id: str
    label: str | None
    state: RequestState
    reason: str | None
    created_at: datetime
    updated_at: datetime
    task: dict[str, Any]
    coalition: list[Assignment] | None = None
    time: float | None = Field(
        None,
        description="T of the coalition now, robot seconds from dispatch (after a replacement, "
        "the latest finish: when each robot was sent plus its t_i)",
    )
    cost: float | None = Field(None, description="C of the coalition now (the sum of its c_i)")
    chosen: FrontMember | None = Field(
        None, description="the point of the Pareto front the selection chose"
    )
    pareto: list[FrontMember] = Field(default_factory=list)
    choices: dict[Literal["balanced", "time", "cost"], int] | None = Field(
        None,
        description="priority -> the index in `pareto` of the member that priority would "
        "choose (docs/model.md, The choice); null when there is no front",
    )
    optimizer: str | None = None
    selection_ms: float | None = None
    history: list[HistoryEntry]


class RequestList(BaseModel):
    items: list[RequestPublic]
    next: str | None = Field(None, description="cursor for the next page (`before=`)")


class SetAsidePublic(BaseModel):
    until: datetime = Field(description="when it may be chosen again (UTC)")
    why: str = Field(description="the failures that set it aside")


class RobotPublic(BaseModel):
    id: str
    cloud: str
    kind: str | None = None
    position: list[float]
    speed: float
    battery: float = Field(description="percent, rounded to 0.1")
    status: str
    capabilities: list[str]
    capability_kinds: dict[str, str] = Field(
        default_factory=dict, description="capability name -> sensing or actuating"
    )
    request: str | None = Field(
        None,
        description="the request the robot is reserved for; null unless the asking "
        "application sent that request",
    )
    progress: Progress | None = Field(
        None, description="how far its task is; null unless the asking application owns it"
    )
    set_aside: SetAsidePublic | None = Field(
        None,
        description="this cloud's selections do not choose the robot until `until`: it "
        "failed requests in a row (no ack, stalled, past its expected finish)",
    )
    refused: str | None = Field(
        None,
        description="why its last state was refused (e.g. its sent_at far from this cloud's "
        "clock), until one is accepted; a robot none of whose states was accepted is listed "
        "offline with this alone",
    )
    seen_ago: float | None = Field(None, description="seconds since its last state message")


class Health(BaseModel):
    status: Literal["ok"]
    cloud: str
    robots: int
    store: str
    time_scale: float = Field(
        1.0, description="robot seconds per wall second (the simulator's --speedup)"
    )


class ErrorBody(BaseModel):
    detail: str
