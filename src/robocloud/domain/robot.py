"""A robot as docs/model.md describes it: where it is, what it can do, what it costs."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Annotated, Literal, Protocol

from pydantic import BaseModel, ConfigDict, Field

from robocloud.errors import explained

# The accepted ranges (docs/model.md). Each keeps every derived number
# (distances, times t_i, costs c_i and their sums over a fleet) finite, so an
# absurd but well-formed value is refused where it enters, naming its field.
MAX_COORDINATE = 1e7  # metres from the origin (10,000 km)
MIN_SPEED, MAX_SPEED = 0.001, 1000.0  # m/s
MAX_AMOUNT = 1e9  # a capability's time (s) or cost, a travel cost per metre
# A name or id: printable, one line. PostgreSQL refuses NUL in text; a
# control character (C0, DEL, C1) in an id would corrupt logs and keys, and a
# bidirectional override (U+202A-U+202E, U+2066-U+2069) would make a log line
# or a page read otherwise than it is written.
NAME_CHARACTERS = r"[^\x00-\x1f\x7f-\x9f\u202a-\u202e\u2066-\u2069]"
NAME_PATTERN = explained(
    f"^{NAME_CHARACTERS}+$",
    "printable text on one line (no control character or bidirectional override)",
)
MAX_NAME_LENGTH = 128
MAX_BATTERY = 100.0

Finite = Annotated[float, Field(allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0.0, le=MAX_AMOUNT, allow_inf_nan=False)]
Coordinate = Annotated[float, Field(ge=-MAX_COORDINATE, le=MAX_COORDINATE, allow_inf_nan=False)]
Position = Annotated[list[Coordinate], Field(min_length=2, max_length=2)]
Speed = Annotated[float, Field(ge=MIN_SPEED, le=MAX_SPEED, allow_inf_nan=False)]
Name = Annotated[str, Field(min_length=1, max_length=MAX_NAME_LENGTH, pattern=NAME_PATTERN)]

RobotStatus = Literal["idle", "reserved", "busy", "charging", "offline"]
ROBOT_STATUSES: tuple[str, ...] = ("idle", "reserved", "busy", "charging", "offline")


class Capability(BaseModel):
    """One sensing or actuating capability of a robot, for one task."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    kind: Literal["sensing", "actuating"]
    time: NonNegative = Field(description="seconds the robot needs to perform the task with it")
    cost: NonNegative = Field(description="what using it costs")


class Robot(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    id: Name
    cloud: Name
    position: Position = Field(description="[x, y] in metres")
    speed: Speed = Field(description="m/s")
    battery: Annotated[float, Field(ge=0.0, le=MAX_BATTERY, allow_inf_nan=False)]
    status: RobotStatus
    travel_cost_per_m: NonNegative
    capabilities: dict[Name, Capability]


# What the selection reads of a robot. ``Robot`` has it, and so has the light
# record ``robocloud select`` decodes a large scenario into (robocloud.cli.
# select_input), validated by the same rules without one pydantic object per robot.
class CapabilityLike(Protocol):
    @property
    def time(self) -> float: ...

    @property
    def cost(self) -> float: ...


class RobotLike(Protocol):
    @property
    def id(self) -> str: ...

    @property
    def cloud(self) -> str: ...

    @property
    def position(self) -> Sequence[float]: ...

    @property
    def speed(self) -> float: ...

    @property
    def battery(self) -> float: ...

    @property
    def status(self) -> str: ...

    @property
    def travel_cost_per_m(self) -> float: ...

    @property
    def capabilities(self) -> Mapping[str, CapabilityLike]: ...
