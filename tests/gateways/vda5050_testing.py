"""What the gateway's tests share: the official schemas, VDA 5050 messages to feed it."""

from __future__ import annotations

import itertools
import json
from typing import Any

import jsonschema_rs
from vda5050_vehicle import SCHEMAS

TOPIC_SCHEMA = {"order": "order", "instantActions": "instantActions"}


def schema_errors(name: str, message: Any) -> list[str]:
    """What the official VDA 5050 schema ``name`` says against ``message`` (empty: valid)."""
    schema = json.loads((SCHEMAS / f"{name}.json").read_text())
    validator = jsonschema_rs.validator_for(schema, validate_formats=True)
    return [f"{e.instance_path}: {e.message}" for e in validator.iter_errors(message)]


HEADER_IDS = itertools.count(1)


def vda_state(**changes: Any) -> dict[str, Any]:
    """A valid VDA 5050 state; each has a new headerId (as an AGV's states do), same timestamp."""
    state: dict[str, Any] = {
        "headerId": next(HEADER_IDS), "timestamp": "2026-11-29T23:00:38.12Z", "version": "2.1.0",
        "manufacturer": "acme", "serialNumber": "agv-1",
        "orderId": "", "orderUpdateId": 0, "lastNodeId": "", "lastNodeSequenceId": 0,
        "nodeStates": [], "edgeStates": [], "driving": False, "actionStates": [],
        "batteryState": {"batteryCharge": 80.0, "charging": False},
        "operatingMode": "AUTOMATIC", "errors": [],
        "safetyState": {"eStop": "NONE", "fieldViolation": False},
        "agvPosition": {"x": 10.0, "y": 5.0, "theta": 0.0, "mapId": "floor-1",
                        "positionInitialized": True},
    }  # fmt: skip
    state.update(changes)
    return state


def factsheet(
    actions: list[str], speed: float = 2.0, state_interval: float | None = None
) -> dict[str, Any]:
    limits = {} if state_interval is None else {
        "protocolLimits": {"timing": {"defaultStateInterval": state_interval}}}  # fmt: skip
    return {
        **limits,
        "protocolFeatures": {
            "optionalParameters": [],
            "agvActions": [{"actionType": a, "actionScopes": ["NODE"]} for a in actions]
            + [{"actionType": "cancelOrder", "actionScopes": ["INSTANT"]}],
        },
        "physicalParameters": {"speedMax": speed},
        "typeSpecification": {"seriesName": "carrier-x"},
    }
