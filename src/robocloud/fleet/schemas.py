"""The robot protocol as JSON Schemas (draft 2020-12), generated from ``robocloud.fleet.messages``.

The pydantic models stay the source of truth; the schemas are what a robot
team written in another language reads. They are checked in under
``docs/protocol/`` (a test fails when they differ from the models) and served
by the IaaS at ``/protocol``. To write them again after changing a model::

    python -m robocloud.fleet.schemas --write docs/protocol
    python -m robocloud.fleet.schemas --check docs/protocol   (exit 1 when they differ)
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pydantic import BaseModel, TypeAdapter

from robocloud.fleet.messages import COMMAND, PROTOCOL_VERSION, STATES, Ack, State, StateError

DRAFT = "https://json-schema.org/draft/2020-12/schema"

# name -> (model, what it is); the files are <name>.schema.json.
MESSAGES: dict[str, tuple[type[BaseModel] | TypeAdapter[Any], str]] = {
    "state": (State, "a robot's state, published on robocloud/<cloud>/robots/<id>/state"),
    "command": (COMMAND, "the payload of a query on robocloud/<cloud>/robots/<id>/cmd"),
    "ack": (Ack, "the robot's one reply to a command, on its cmd key"),
    "states": (
        STATES,
        "a fleet gateway's batch of its robots' states, published on "
        "robocloud/<cloud>/fleets/<gateway>/states",
    ),
    "error": (
        StateError,
        "the IaaS's answer to a refused state, on robocloud/<cloud>/robots/<id>/error",
    ),
}


def schema_id(name: str) -> str:
    """The schema's ``$id``: a URN carrying the protocol version (no host to fetch it from)."""
    return f"urn:robocloud:protocol:{PROTOCOL_VERSION}:{name}"


def protocol_schema(name: str) -> dict[str, Any]:
    """The JSON Schema of one message (``state``, ``command``, ``ack`` or ``error``)."""
    model, what = MESSAGES[name]
    if isinstance(model, TypeAdapter):
        body = model.json_schema(mode="validation")
    else:
        body = model.model_json_schema(mode="validation")
    head = {
        "$schema": DRAFT,
        "$id": schema_id(name),
        "title": body.pop("title", name),
        "description": f"robocloud robot protocol {PROTOCOL_VERSION}: {what}.",
        "x-robocloud-protocol": PROTOCOL_VERSION,
    }
    body.pop("description", None)  # the model's docstring: Python prose, not the contract
    _as_validated(body)
    return {**head, **body}


def _as_validated(schema: dict[str, Any]) -> None:
    """Say what pydantic's own schema leaves out of what the models refuse.

    A command's ``type`` has a default in Python but picks the model on the
    wire, so it is required there; a map whose keys do not match the name
    pattern is refused, not ignored.
    """
    for definition in schema.get("$defs", {}).values():
        if "type" in definition.get("properties", {}) and "discriminator" in schema:
            definition["required"] = ["type", *definition.get("required", [])]
    for node in _objects(schema):
        if "patternProperties" in node and "additionalProperties" not in node:
            node["additionalProperties"] = False


def _objects(node: Any) -> list[dict[str, Any]]:
    found = []
    if isinstance(node, dict):
        found.append(node)
        for value in node.values():
            found += _objects(value)
    elif isinstance(node, list):
        for value in node:
            found += _objects(value)
    return found


def protocol_schemas() -> dict[str, dict[str, Any]]:
    return {name: protocol_schema(name) for name in MESSAGES}


def schema_text(name: str) -> str:
    """The schema as the checked-in file holds it."""
    return json.dumps(protocol_schema(name), indent=2, ensure_ascii=False) + "\n"


def file_name(name: str) -> str:
    return f"{name}.schema.json"


def differences(folder: Path) -> list[str]:
    """A sentence for each schema file in ``folder`` that is missing or differs from the models."""
    out = []
    for name in MESSAGES:
        path = folder / file_name(name)
        if not path.is_file():
            out.append(f"{path} is missing.")
        elif path.read_text(encoding="utf-8") != schema_text(name):
            out.append(f"{path} differs from robocloud.fleet.messages.")
    return out


def write(folder: Path) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for name in MESSAGES:
        path = folder / file_name(name)
        path.write_text(schema_text(name), encoding="utf-8")
        written.append(path)
    return written


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m robocloud.fleet.schemas",
        description="Write or check the robot protocol's JSON Schemas.",
    )
    action = parser.add_mutually_exclusive_group(required=True)
    action.add_argument("--write", metavar="FOLDER", type=Path, help="write them there")
    action.add_argument("--check", metavar="FOLDER", type=Path, help="exit 1 if they differ")
    args = parser.parse_args(argv)
    if args.write is not None:
        for path in write(args.write):
            print(path)
        return 0
    problems = differences(args.check)
    for problem in problems:
        print(problem, file=sys.stderr)
    if problems:
        print(f"run: python -m robocloud.fleet.schemas --write {args.check}", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
