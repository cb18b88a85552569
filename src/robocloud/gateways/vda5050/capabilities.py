"""The gateway's capabilities file: which VDA 5050 actions are which robocloud capabilities.

A factsheet lists the actions an AGV can do (``protocolFeatures.agvActions``)
but not what robocloud needs to choose it: a capability's kind, time and cost.
The file gives them, per capability, with the action that carries it out::

    {"capabilities": {
       "lift":  {"kind": "actuating", "time": 20.0, "cost": 4.0, "action": "pick",
                 "parameters": [{"key": "stationType", "value": "floor"}]},
       "scan":  {"kind": "sensing", "time": 5.0, "cost": 1.0, "action": "detectObject"}},
     "travel_cost_per_m": 0.05, "speed": 1.0, "min_battery": 10.0}

An AGV has a capability when its factsheet lists the capability's ``action``
with the scope ``NODE`` (the gateway puts it on the order's last node).
``speed`` (m/s) stands in for a factsheet without ``physicalParameters.speedMax``;
an AGV whose battery is below ``min_battery`` percent refuses tasks.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from robocloud.domain import Capability
from robocloud.domain.robot import Name, NonNegative, Speed
from robocloud.gateways.json_file import read_json_file, validated


class ActionParameter(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    key: Annotated[str, Field(min_length=1, max_length=128)]
    value: Any = Field(description="any JSON value: string, number, boolean, array or object")


class CapabilityAction(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Literal["sensing", "actuating"]
    time: NonNegative = Field(description="seconds of work at the task's location")
    cost: NonNegative
    action: Name = Field(description="the VDA 5050 actionType that carries it out")
    parameters: list[ActionParameter] = Field(default_factory=list)

    def capability(self) -> Capability:
        return Capability(kind=self.kind, time=self.time, cost=self.cost)


class GatewayCapabilities(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    capabilities: dict[Name, CapabilityAction] = Field(default_factory=dict)
    travel_cost_per_m: NonNegative = 0.05
    speed: Speed = Field(1.0, description="m/s, when a factsheet gives no speedMax")
    min_battery: Annotated[float, Field(ge=0.0, le=100.0, allow_inf_nan=False)] = 10.0

    def offered(self, actions: frozenset[str]) -> dict[str, Capability]:
        """The capabilities whose action is among an AGV's node ``actions``."""
        return {
            name: entry.capability()
            for name, entry in self.capabilities.items()
            if entry.action in actions
        }


def load_capabilities(path: str | None) -> GatewayCapabilities:
    """The file at ``path``, checked; none at all without a path (no AGV can then be chosen)."""
    if path is None:
        return GatewayCapabilities()
    data = read_json_file(path, "--capabilities", "capabilities file")
    return validated(GatewayCapabilities, data, path, "--capabilities")
