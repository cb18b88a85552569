"""VDA 5050 2.x messages: the fields the gateway reads, and the messages it writes.

Topics are ``<interface>/<major>/<manufacturer>/<serialNumber>/<topic>``. The
gateway reads ``connection``, ``state``, ``factsheet`` and ``visualization``
and writes ``order`` and ``instantActions``; what it writes validates against
the VDA 5050 2.x JSON schemas (in the tests, as the PyPI package vda5050-sdk ships them).

The models below read only what the gateway uses, leniently (other fields are
ignored), but a field it uses must be there with the right type: a message
without it is refused with a sentence naming it.
"""

from __future__ import annotations

import datetime as dt
import itertools
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

VERSION = "2.1.0"  # the protocol version the gateway writes in its headers
MAJOR = "v2"  # the topic's major version: the gateway speaks 2.x only
READ = ("connection", "state", "factsheet", "visualization")
WRITE = ("order", "instantActions")
ActionStatus = Literal["WAITING", "INITIALIZING", "RUNNING", "PAUSED", "FINISHED", "FAILED"]
Blocking = Literal["NONE", "SOFT", "HARD"]

_LENIENT = ConfigDict(extra="ignore", frozen=True)


@dataclass(frozen=True)
class AgvName:
    """One AGV of the broker, as its topics name it."""

    manufacturer: str
    serial: str

    def topic(self, interface: str, major: str, what: str) -> str:
        return f"{interface}/{major}/{self.manufacturer}/{self.serial}/{what}"


def parse_topic(topic: str, interface: str, major: str) -> tuple[AgvName, str] | None:
    """``(the AGV, what)`` of a topic the gateway subscribed to; None for another topic."""
    parts = topic.split("/")
    if len(parts) != 5 or parts[0] != interface or parts[1] != major or not all(parts):
        return None
    return AgvName(parts[2], parts[3]), parts[4]


# -- what the gateway reads ------------------------------------------------------------


class Connection(BaseModel):
    model_config = _LENIENT

    connectionState: Literal["ONLINE", "OFFLINE", "CONNECTIONBROKEN"]


class AgvPosition(BaseModel):
    model_config = _LENIENT

    x: float = Field(allow_inf_nan=False)
    y: float = Field(allow_inf_nan=False)
    mapId: str = ""
    positionInitialized: bool = True


class BatteryState(BaseModel):
    model_config = _LENIENT

    batteryCharge: float = Field(allow_inf_nan=False)
    charging: bool = False


class NodeState(BaseModel):
    model_config = _LENIENT

    nodeId: str
    sequenceId: int


class ActionState(BaseModel):
    model_config = _LENIENT

    actionId: str
    actionType: str | None = None
    actionStatus: ActionStatus
    resultDescription: str | None = None


class ErrorReference(BaseModel):
    model_config = _LENIENT

    referenceKey: str
    referenceValue: str


class AgvError(BaseModel):
    model_config = _LENIENT

    errorType: str
    errorLevel: Literal["WARNING", "FATAL"]
    errorReferences: list[ErrorReference] = Field(default_factory=list)
    errorDescription: str = ""

    def refers_to(self, key: str, value: str) -> bool:
        refs = self.errorReferences
        return any(r.referenceKey == key and r.referenceValue == value for r in refs)

    def sentence(self) -> str:
        text = f"{self.errorType} ({self.errorLevel.lower()})"
        return f"{text}: {self.errorDescription}" if self.errorDescription else text


class VdaState(BaseModel):
    """The AGV's state message, as far as the gateway reads it."""

    model_config = _LENIENT

    headerId: int = Field(ge=0)
    timestamp: dt.datetime
    orderId: str
    orderUpdateId: int = Field(ge=0)
    lastNodeId: str = ""
    nodeStates: list[NodeState]
    edgeStates: list[dict[str, Any]]
    actionStates: list[ActionState]
    batteryState: BatteryState
    operatingMode: str
    errors: list[AgvError]
    driving: bool
    agvPosition: AgvPosition | None = None

    def action(self, action_id: str) -> ActionState | None:
        for state in self.actionStates:
            if state.actionId == action_id:
                return state
        return None

    def sent_at(self) -> float:
        """``timestamp`` as unix seconds; one without a zone is taken as UTC."""
        moment = self.timestamp
        if moment.tzinfo is None:
            moment = moment.replace(tzinfo=dt.UTC)
        return moment.timestamp()

    def timestamp_text(self) -> str:
        return timestamp(self.sent_at())


class AgvAction(BaseModel):
    model_config = _LENIENT

    actionType: str
    actionScopes: list[str]


class ProtocolFeatures(BaseModel):
    model_config = _LENIENT

    agvActions: list[AgvAction]


class PhysicalParameters(BaseModel):
    model_config = _LENIENT

    speedMax: float | None = Field(None, allow_inf_nan=False)


class TypeSpecification(BaseModel):
    model_config = _LENIENT

    seriesName: str = ""


class Timing(BaseModel):
    model_config = _LENIENT

    defaultStateInterval: float | None = Field(None, allow_inf_nan=False)


class ProtocolLimits(BaseModel):
    model_config = _LENIENT

    timing: Timing | None = None


class Factsheet(BaseModel):
    model_config = _LENIENT

    protocolFeatures: ProtocolFeatures
    physicalParameters: PhysicalParameters | None = None
    typeSpecification: TypeSpecification | None = None
    protocolLimits: ProtocolLimits | None = None

    def state_interval(self) -> float | None:
        """Seconds between two states the AGV promises (``defaultStateInterval``), if it says."""
        limits = self.protocolLimits
        interval = limits.timing.defaultStateInterval if limits and limits.timing else None
        return interval if interval is not None and interval > 0 else None

    def node_actions(self) -> frozenset[str]:
        return frozenset(
            a.actionType for a in self.protocolFeatures.agvActions if "NODE" in a.actionScopes
        )


class Visualization(BaseModel):
    model_config = _LENIENT

    agvPosition: AgvPosition | None = None


# -- what the gateway writes ------------------------------------------------------------


def timestamp(unix: float) -> str:
    """ISO 8601 in UTC with hundredths, as VDA 5050 shows it: ``2026-11-29T23:00:38.12Z``."""
    moment = dt.datetime.fromtimestamp(unix, dt.UTC)
    return moment.strftime("%Y-%m-%dT%H:%M:%S.") + f"{moment.microsecond // 10_000:02d}Z"


class Headers:
    """The header of each message: ``headerId`` counts per topic, from 0."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._counters: dict[str, itertools.count[int]] = {}

    def header(self, agv: AgvName, topic: str, unix: float) -> dict[str, Any]:
        with self._lock:
            key = f"{agv.manufacturer}/{agv.serial}/{topic}"
            counter = self._counters.setdefault(key, itertools.count())
            header_id = next(counter)
        return {
            "headerId": header_id,
            "timestamp": timestamp(unix),
            "version": VERSION,
            "manufacturer": agv.manufacturer,
            "serialNumber": agv.serial,
        }


@dataclass(frozen=True)
class NodeAction:
    action_type: str
    action_id: str
    blocking: Blocking
    parameters: Sequence[dict[str, Any]] = ()

    def to_json(self) -> dict[str, Any]:
        action: dict[str, Any] = {
            "actionType": self.action_type,
            "actionId": self.action_id,
            "blockingType": self.blocking,
        }
        if self.parameters:
            action["actionParameters"] = [dict(p) for p in self.parameters]
        return action


def order(
    header: dict[str, Any],
    order_id: str,
    start: tuple[float, float],
    target: tuple[float, float],
    map_id: str,
    actions: Sequence[NodeAction],
) -> dict[str, Any]:
    """An order of two nodes, where the AGV is and the task's location, and the edge between.

    The node at the location carries the capabilities' actions; every node
    and the edge are released (the whole order is the base).
    """
    first, last, edge = f"{order_id}-start", f"{order_id}-end", f"{order_id}-edge"
    return {
        **header,
        "orderId": order_id,
        "orderUpdateId": 0,
        "nodes": [
            {
                "nodeId": first,
                "sequenceId": 0,
                "released": True,
                "nodePosition": {"x": start[0], "y": start[1], "mapId": map_id},
                "actions": [],
            },
            {
                "nodeId": last,
                "sequenceId": 2,
                "released": True,
                "nodePosition": {"x": target[0], "y": target[1], "mapId": map_id},
                "actions": [a.to_json() for a in actions],
            },
        ],
        "edges": [
            {
                "edgeId": edge,
                "sequenceId": 1,
                "released": True,
                "startNodeId": first,
                "endNodeId": last,
                "actions": [],
            }
        ],
    }


def instant_actions(header: dict[str, Any], actions: Sequence[NodeAction]) -> dict[str, Any]:
    return {**header, "actions": [a.to_json() for a in actions]}


def cancel_order(header: dict[str, Any], action_id: str) -> dict[str, Any]:
    return instant_actions(header, [NodeAction("cancelOrder", action_id, "HARD")])


def factsheet_request(header: dict[str, Any], action_id: str) -> dict[str, Any]:
    return instant_actions(header, [NodeAction("factsheetRequest", action_id, "NONE")])
