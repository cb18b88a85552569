"""A task request as MODEL.md fixes it, and the thesis's Criteria_Importance."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator
from pydantic.config import JsonDict

from robocloud.domain.robot import Name, Position

# Documented bounds (docs/model.md): a coalition of more than MAX_COUNT robots
# for one capability is beyond any fleet this system is sized for; limits past
# these are no limits and only risk overflow.
MAX_COUNT = 1_000
MAX_ROBOTS = 100_000
MAX_COST = 1e12
MAX_TIME = 1e9  # seconds (about 31 years)

Count = Annotated[int, Field(ge=1, le=MAX_COUNT)]
Priority = Literal["balanced", "time", "cost"]
Execution = Literal["parallel", "sequential"]

# The thesis's Criteria_Importance codes (Algorithm 3, steps 3 to 9).
CRITERIA_IMPORTANCE: dict[str, int] = {"balanced": 0, "time": 1, "cost": 2}


# The rule "at least one capability", for readers of the JSON Schema (the
# validator below enforces it, with the rule that no name is in both).
AT_LEAST_ONE_CAPABILITY: JsonDict = {
    "anyOf": [
        {"required": ["sensing"], "properties": {"sensing": {"minProperties": 1}}},
        {"required": ["actuating"], "properties": {"actuating": {"minProperties": 1}}},
    ]
}


class Task(BaseModel):
    model_config = ConfigDict(
        strict=True, extra="forbid", frozen=True, json_schema_extra=AT_LEAST_ONE_CAPABILITY
    )

    location: Position = Field(description="[x, y] in metres")
    sensing: dict[Name, Count] = Field(default_factory=dict)
    actuating: dict[Name, Count] = Field(default_factory=dict)
    max_robots: Annotated[int, Field(ge=1, le=MAX_ROBOTS)]
    max_cost: Annotated[float, Field(ge=0.0, le=MAX_COST, allow_inf_nan=False)]
    max_time: Annotated[float, Field(ge=0.0, le=MAX_TIME, allow_inf_nan=False)] = Field(
        description="seconds"
    )
    min_battery: Annotated[float, Field(ge=0.0, le=100.0, allow_inf_nan=False)] = 0.0
    priority: Priority = "balanced"
    execution: Execution = "parallel"

    @model_validator(mode="after")
    def _requires_something(self) -> Task:
        if not self.sensing and not self.actuating:
            raise ValueError("a task must require at least one sensing or actuating capability")
        both = sorted(set(self.sensing) & set(self.actuating))
        if both:
            raise ValueError(f"capability {both[0]!r} is listed as both sensing and actuating")
        return self

    @property
    def required(self) -> dict[str, int]:
        """Capability name -> how many distinct robots must bring it, names sorted."""
        merged = {**self.sensing, **self.actuating}
        return {name: merged[name] for name in sorted(merged)}
