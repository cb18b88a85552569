"""A task request as docs/model.md fixes it, and the thesis's Criteria_Importance."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, model_validator
from pydantic.config import JsonDict

from robocloud.domain.robot import Name, Position

# Documented bounds (docs/model.md): a coalition of more than MAX_COUNT robots
# for one capability is beyond any fleet this system is sized for; limits past
# these are no limits and only risk overflow.
MAX_COUNT = 1_000
MAX_ROBOTS = 100_000
MAX_COST = 1e12
MAX_TIME = 1e9  # seconds (about 31 years)
# Capabilities a task may name, sensing and actuating together: a fleet's robots
# bring a few dozen kinds; more only make every selection and every question
# to the other clouds longer (their idle-robot query carries the names).
MAX_CAPABILITIES = 100


def _integral(value: object) -> object:
    """3.0 is the integer 3, as JSON Schema's ``integer`` says; 3.5 stays a float (refused)."""
    if isinstance(value, float) and value.is_integer():
        return int(value)
    return value


Count = Annotated[int, Field(ge=1, le=MAX_COUNT), BeforeValidator(_integral)]
Priority = Literal["balanced", "time", "cost"]
Execution = Literal["parallel", "sequential"]

# The thesis's Criteria_Importance codes (Algorithm 3, steps 3 to 9).
CRITERIA_IMPORTANCE: dict[str, int] = {"balanced": 0, "time": 1, "cost": 2}


def _task_schema(schema: JsonDict) -> None:
    """The JSON Schema says what the validators check, for clients and fuzzers.

    The rule "at least one capability" (the validator below enforces it, with
    the rule that no name is in both), and the capability names' pattern as a
    rule on the names (pydantic writes it as ``patternProperties``, which
    would let names that do not match through).
    """
    schema["anyOf"] = [
        {"required": ["sensing"], "properties": {"sensing": {"minProperties": 1}}},
        {"required": ["actuating"], "properties": {"actuating": {"minProperties": 1}}},
    ]
    properties = schema["properties"]
    assert isinstance(properties, dict)
    for kind in ("sensing", "actuating"):
        counts = properties[kind]
        assert isinstance(counts, dict)
        patterns = counts.pop("patternProperties", None)
        if isinstance(patterns, dict) and len(patterns) == 1:
            [(pattern, value)] = patterns.items()
            names = counts.setdefault("propertyNames", {})
            assert isinstance(names, dict)
            names["pattern"] = pattern
            counts["additionalProperties"] = value


class Task(BaseModel):
    model_config = ConfigDict(
        strict=True, extra="forbid", frozen=True, json_schema_extra=_task_schema
    )

    location: Position = Field(description="[x, y] in metres")
    sensing: dict[Name, Count] = Field(default_factory=dict, max_length=MAX_CAPABILITIES)
    actuating: dict[Name, Count] = Field(default_factory=dict, max_length=MAX_CAPABILITIES)
    max_robots: Annotated[int, Field(ge=1, le=MAX_ROBOTS), BeforeValidator(_integral)]
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
        named = len(self.sensing) + len(self.actuating)
        if named > MAX_CAPABILITIES:
            raise ValueError(
                f"a task may require at most {MAX_CAPABILITIES} capabilities, sensing and "
                f"actuating together, not {named}"
            )
        both = sorted(set(self.sensing) & set(self.actuating))
        if both:
            raise ValueError(f"capability {both[0]!r} is listed as both sensing and actuating")
        return self

    @property
    def required(self) -> dict[str, int]:
        """Capability name -> how many distinct robots must bring it, names sorted."""
        merged = {**self.sensing, **self.actuating}
        return {name: merged[name] for name in sorted(merged)}
