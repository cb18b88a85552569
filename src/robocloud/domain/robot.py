"""A robot as MODEL.md describes it: where it is, what it can do, what it costs."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

Finite = Annotated[float, Field(allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Position = Annotated[list[Finite], Field(min_length=2, max_length=2)]
Name = Annotated[str, Field(min_length=1, max_length=128)]

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
    speed: Annotated[float, Field(gt=0.0, allow_inf_nan=False)] = Field(description="m/s")
    battery: Annotated[float, Field(ge=0.0, le=100.0, allow_inf_nan=False)]
    status: RobotStatus
    travel_cost_per_m: NonNegative
    capabilities: dict[Name, Capability]
