"""The robot protocol's JSON Schemas: checked in, equal to the models, and as strict as they are."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import jsonschema_rs
import pydantic
import pytest

from robocloud.fleet import schemas
from robocloud.fleet.ingest import Refusal, StateReader
from robocloud.fleet.messages import COMMAND, PROTOCOL_VERSION, STATES, Ack, State, StateError

DOCS = Path(__file__).parents[2] / "docs" / "protocol"

STATE: dict[str, Any] = {
    "id": "a-0001", "cloud": "cloud-a", "kind": "tribot", "position": [120.0, 40.5],
    "speed": 1.5, "battery": 86.0, "status": "busy", "travel_cost_per_m": 0.05,
    "capabilities": {"grabber": {"kind": "actuating", "time": 90.0, "cost": 8.0}},
    "task": {"request_id": "req-x", "phase": "travel", "progress": 0.25,
             "capabilities": ["grabber"]},
    "last_task": None, "seq": 1042, "sent_at": 1767225600.25,
}  # fmt: skip
ASSIGN = {"type": "assign", "request_id": "req-x", "location": [400.0, 310.0],
          "capabilities": ["grabber"], "execution": "parallel"}  # fmt: skip
CANCEL = {"type": "cancel", "request_id": "req-x"}
ACK = {"ok": False, "robot": "a-0001", "request_id": "req-x", "error": "robot a-0001 is busy."}
ERROR = {"robot": "a-0001", "field": "battery", "error": "battery: too much.", "sent_at": 1.0}


def changed(message: dict[str, Any], path: str, value: Any) -> dict[str, Any]:
    """``message`` with the field at ``path`` (dots) set to ``value``, or removed for ...."""
    out = copy.deepcopy(message)
    *parents, last = path.split(".")
    node = out
    for part in parents:
        node = node[part]
    if value is ...:
        del node[last]
    else:
        node[last] = value
    return out


def model_accepts(name: str, message: Any) -> bool:
    validate = {
        "state": State.model_validate_json,
        "command": COMMAND.validate_json,
        "ack": Ack.model_validate_json,
        "error": StateError.model_validate_json,
        "states": STATES.validate_json,
    }[name]
    try:
        validate(json.dumps(message))
    except pydantic.ValidationError:
        return False
    return True


def schema_accepts(name: str, message: Any) -> bool:
    validator = jsonschema_rs.validator_for(schemas.protocol_schema(name))
    return bool(validator.is_valid(message))


def test_the_checked_in_schemas_are_those_of_the_models() -> None:
    assert schemas.differences(DOCS) == [], (
        "the models changed: run python -m robocloud.fleet.schemas --write docs/protocol"
    )


def test_check_says_which_file_differs_and_how_to_fix_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert schemas.main(["--write", str(tmp_path)]) == 0
    assert schemas.main(["--check", str(tmp_path)]) == 0
    stale = tmp_path / "state.schema.json"
    stale.write_text(stale.read_text().replace('"battery"', '"charge"'))
    (tmp_path / "ack.schema.json").unlink()
    capsys.readouterr()
    assert schemas.main(["--check", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert "state.schema.json differs" in err
    assert "ack.schema.json is missing" in err
    assert "--write" in err


@pytest.mark.parametrize("name", list(schemas.MESSAGES))
def test_each_schema_is_draft_2020_12_and_carries_the_version(name: str) -> None:
    schema = schemas.protocol_schema(name)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert jsonschema_rs.meta.is_valid(schema)
    assert schema["$id"] == f"urn:robocloud:protocol:{PROTOCOL_VERSION}:{name}"
    assert schema["x-robocloud-protocol"] == PROTOCOL_VERSION


def test_required_fields_are_the_models_required_fields() -> None:
    state = schemas.protocol_schema("state")
    assert set(state["required"]) == {
        name for name, field in State.model_fields.items() if field.is_required()
    }
    assert {"task", "last_task"}.isdisjoint(state["required"])
    command = schemas.protocol_schema("command")
    for name in ("Assign", "Cancel"):
        assert command["$defs"][name]["required"][0] == "type"


CASES = [
    ("state", STATE, True),
    ("state", changed(STATE, "task", None), True),
    ("state", changed(STATE, "last_task", ...), True),
    ("state", changed(STATE, "colour", "red"), True),  # unknown fields are ignored
    ("state", changed(STATE, "kind", ...), False),
    ("state", changed(STATE, "battery", 100.5), False),
    ("state", changed(STATE, "status", "working"), False),
    ("state", changed(STATE, "position", [1.0]), False),
    ("state", changed(STATE, "position", [2e7, 0.0]), False),
    ("state", changed(STATE, "speed", 0.0), False),
    ("state", changed(STATE, "seq", -1), False),
    ("state", changed(STATE, "task.phase", "parked"), False),
    ("state", changed(STATE, "task.progress", 1.5), False),
    ("state", changed(STATE, "capabilities.grabber.kind", "both"), False),
    ("state", changed(STATE, "capabilities.grabber.size", 3), False),
    ("state", changed(STATE, "capabilities", {"bad\nname": STATE["capabilities"]["grabber"]}),
     False),
    ("state", changed(STATE, "id", ""), False),
    ("command", ASSIGN, True),
    ("command", changed(ASSIGN, "execution", ...), True),
    ("command", changed(ASSIGN, "type", ...), False),
    ("command", changed(ASSIGN, "capabilities", []), False),
    ("command", changed(ASSIGN, "execution", "random"), False),
    ("command", CANCEL, True),
    ("command", changed(CANCEL, "type", "stop"), False),
    ("command", changed(CANCEL, "request_id", ...), False),
    ("ack", ACK, True),
    ("ack", changed(ACK, "request_id", None), True),
    ("ack", changed(ACK, "ok", ...), False),
    ("ack", changed(ACK, "robot", ...), False),
    ("states", [STATE, changed(STATE, "id", "a-0002")], True),
    ("states", [], True),
    ("states", [STATE, changed(STATE, "battery", 100.5)], False),
    ("states", STATE, False),
    ("error", ERROR, True),
    ("error", changed(ERROR, "field", ...), False),
]  # fmt: skip


@pytest.mark.parametrize(("name", "message", "valid"), CASES)
def test_the_schema_accepts_what_the_model_accepts(
    name: str, message: Any, valid: bool
) -> None:
    assert model_accepts(name, message) is valid
    assert schema_accepts(name, message) is valid


def test_the_schema_is_stricter_where_the_model_is_lenient() -> None:
    # The model alone reads leniently (a number in a string); the contract is
    # the schema, and the IaaS's reader refuses what the schema refuses.
    message = changed(STATE, "battery", "86")
    assert model_accepts("state", message)
    assert not schema_accepts("state", message)
    refused = StateReader().read(json.dumps(message).encode())
    assert isinstance(refused, Refusal) and refused.field == "battery"
