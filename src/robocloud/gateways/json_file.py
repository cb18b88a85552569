"""A gateway's JSON file (NXT bricks, ROS 2 robots, VDA 5050 capabilities), read and checked.

Every fault is an error with a sentence naming the file, and the flag that
named it: too large, missing, not UTF-8, not readable, not JSON, or not what
its model accepts (the field at fault named).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TypeVar

import pydantic

from robocloud.errors import InvalidInput, NotFound, describe_validation_errors

MAX_FILE_BYTES = 1024 * 1024

Model = TypeVar("Model", bound=pydantic.BaseModel)


def read_json_file(path: str, flag: str, kind: str) -> object:
    """The JSON in the file at ``path`` (a ``kind``, e.g. "bricks file", named by ``flag``)."""
    file = Path(path)
    try:
        size = file.stat().st_size
        if size > MAX_FILE_BYTES:
            raise InvalidInput(
                f"{path} is {size} bytes; a {kind} is at most {MAX_FILE_BYTES}.", flag
            )
        text = file.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise NotFound(f"{path}: no such file.", path) from None
    except UnicodeDecodeError:
        raise InvalidInput(f"{path} is not UTF-8 text.", flag) from None
    except OSError as error:
        raise InvalidInput(f"cannot read {path}: {error.strerror or error}.", flag) from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as error:
        raise InvalidInput(
            f"{path} is not valid JSON: {error.msg} at line {error.lineno} column {error.colno}.",
            flag,
        ) from None


def validated(model: type[Model], data: object, source: str, flag: str) -> Model:
    """``data`` as ``model``; else InvalidInput naming ``source`` and the field at fault."""
    try:
        return model.model_validate(data)
    except pydantic.ValidationError as error:
        described = describe_validation_errors(error.errors())
        raise InvalidInput(f"{source}: {described.message}", flag) from None
