"""The task's bounds as the IaaS's own OpenAPI document states them, for the page's form.

The page checks a task before sending it, so an operator sees "at most 1,000"
beside the field rather than a refusal later. The numbers are the IaaS's, read
once from its ``/openapi.json`` (the schema of ``POST /v1/requests``), never a
copy kept here: when the IaaS's bounds change, the form follows. A document
that does not say a bound leaves it out; the page then leaves that check to
the IaaS, whose sentence comes back as it is.

::

    {"count": {"min": 1, "max": 1000},           # robots per capability
     "max_robots": {"min": 1, "max": 100000},
     "max_cost": {"min": 0, "max": 1e12},
     "max_time": {"min": 0, "max": 1e9},
     "min_battery": {"min": 0, "max": 100},
     "label": {"max_length": 200}}
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

CREATE_PATH = "/v1/requests"
NUMBERS = ("max_robots", "max_cost", "max_time", "min_battery")
MAX_REF_DEPTH = 8  # a $ref chain longer than this is a broken document, not a schema


def task_limits(spec: Any) -> dict[str, dict[str, float]] | None:
    """The bounds of a task in ``spec`` (an OpenAPI document), or None if it has no task schema."""
    task = _task_schema(spec)
    if task is None:
        return None
    properties = task.get("properties")
    if not isinstance(properties, Mapping):
        return None
    limits: dict[str, dict[str, float]] = {}
    for name in NUMBERS:
        bounds = _bounds(_resolve(spec, properties.get(name)))
        if bounds:
            limits[name] = bounds
    for kind in ("actuating", "sensing"):
        counts = _resolve(spec, properties.get(kind))
        if isinstance(counts, Mapping):
            bounds = _bounds(_resolve(spec, counts.get("additionalProperties")))
            if bounds:
                limits["count"] = bounds
                break
    label = _resolve(spec, properties.get("label"))
    for option in _options(spec, label):
        longest = option.get("maxLength")
        if isinstance(longest, int) and not isinstance(longest, bool):
            limits["label"] = {"max_length": float(longest)}
            break
    return limits


def _task_schema(spec: Any) -> Mapping[str, Any] | None:
    if not isinstance(spec, Mapping):
        return None
    paths = spec.get("paths")
    path = paths.get(CREATE_PATH) if isinstance(paths, Mapping) else None
    operation = path.get("post") if isinstance(path, Mapping) else None
    if not isinstance(operation, Mapping):
        return None
    body = operation.get("requestBody")
    content = body.get("content") if isinstance(body, Mapping) else None
    json_body = content.get("application/json") if isinstance(content, Mapping) else None
    schema = _resolve(spec, json_body.get("schema") if isinstance(json_body, Mapping) else None)
    return schema if isinstance(schema, Mapping) else None


def _resolve(spec: Mapping[str, Any], schema: Any) -> Any:
    """``schema`` with its ``$ref`` (a local ``#/...`` pointer) followed."""
    for _ in range(MAX_REF_DEPTH):
        if not (isinstance(schema, Mapping) and isinstance(schema.get("$ref"), str)):
            return schema
        ref: str = schema["$ref"]
        if not ref.startswith("#/"):
            return None
        node: Any = spec
        for part in ref[2:].split("/"):
            node = node.get(part) if isinstance(node, Mapping) else None
        schema = node
    return None


def _options(spec: Mapping[str, Any], schema: Any) -> list[Mapping[str, Any]]:
    """A schema, or each branch of its ``anyOf`` (an optional field is ``T`` or null)."""
    if not isinstance(schema, Mapping):
        return []
    branches = schema.get("anyOf")
    if isinstance(branches, list):
        return [b for b in (_resolve(spec, b) for b in branches) if isinstance(b, Mapping)]
    return [schema]


def _bounds(schema: Any) -> dict[str, float]:
    if not isinstance(schema, Mapping):
        return {}
    out: dict[str, float] = {}
    for key, name in (("minimum", "min"), ("maximum", "max")):
        if _finite(schema.get(key)):
            out[name] = float(schema[key])
    return out


def _finite(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
