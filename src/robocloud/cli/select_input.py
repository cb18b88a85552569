"""Reading ``robocloud select``'s input: ``{"robots": [...], "task": {...}}``.

Two readers, one set of rules (docs/model.md) and the same sentences:

- :func:`parse_select_input`, the *objects* reader: ``json.loads``, then one
  validated pydantic :class:`~robocloud.domain.Robot` per robot. It takes
  about 45 microseconds a robot, 45 s for a million.
- :func:`read_candidates`, the *columnar* reader (the default): msgspec
  splits the document without building the robots (``robots`` as raw JSON
  slices, ``task`` likewise), then decodes the robots in pieces of
  ``CHUNK`` into light :class:`RobotRecord` structs that msgspec validates
  against the same limits as ``Robot`` while it decodes, and filters each
  piece at once (``filter_robots``, the pipeline's own filter). Only the
  candidates, the ids (for the uniqueness rule) and one piece are held at a
  time; the selection then reads the candidates' fields as columns
  (``CoalitionProblem.build`` takes any ``RobotLike``), so its numbers are
  those of the objects reader, bit for bit.

Bad input costs nothing on the fast path: where msgspec refuses a robot,
the robots from the first refused piece on are checked one by one and each
refused robot is validated by pydantic, so the sentence is the objects
reader's (the first problem, its field, and how many more). Whatever msgspec
refuses that pydantic would take (or any other surprise: a document msgspec
cannot split) goes to the objects reader whole, so the answer is always the
objects reader's answer; only its speed differs.

The names' rule (printable, one line) costs a regular expression per name;
it is only checked by msgspec when the document holds a backslash or a DEL
byte anywhere, since otherwise no string in it can hold a control character
(JSON forbids them raw in strings; only an escape can make one).
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal, NoReturn

import msgspec
from pydantic import TypeAdapter, ValidationError

from robocloud.domain import Robot, RobotLike, Task
from robocloud.domain.records import (
    CheckedRobotRecord,
    RobotRecord,
    may_hold_control_characters,
)
from robocloud.errors import InvalidInput, describe_validation_errors
from robocloud.selection.filtering import filter_robots

INPUT_FIELDS = ("robots", "task")
# Robots decoded at a time: enough that a call's overhead vanishes, few enough
# that a piece's objects stay in the CPU's caches until they are filtered and
# freed (benchmarks/results/design-notes.md, select-chunk).
CHUNK = 500

# --- the objects reader ----------------------------------------------------------


def parse_select_input(text: str, source: str = "the input") -> tuple[list[Robot], Task]:
    """docs/model.md's ``{"robots": [...], "task": {...}}``, validated, ids unique."""
    try:
        data = json.loads(text, parse_constant=_reject_constant)
    except json.JSONDecodeError as error:
        raise InvalidInput(
            f"{source} is not valid JSON: {error.msg} at line {error.lineno} column {error.colno}."
        ) from None
    if not isinstance(data, dict):
        raise InvalidInput(
            f"{source} must be a JSON object with robots and task, not {_json_type(data)}."
        )
    for name in INPUT_FIELDS:
        if name not in data:
            raise InvalidInput(f"{name} is missing.", field=name)
    unknown = sorted(set(data) - set(INPUT_FIELDS))
    if unknown:
        raise InvalidInput(f"{unknown[0]} is not a known field.", field=unknown[0])
    try:
        robots = TypeAdapter(list[Robot]).validate_python(data["robots"])
    except ValidationError as error:
        raise describe_validation_errors(error.errors(), "robots") from None
    task = _validate_task(data["task"])
    check_unique_ids([robot.id for robot in robots])
    return robots, task


def check_unique_ids(ids: Sequence[str]) -> None:
    """The first id that repeats an earlier one, named with both indices."""
    first: dict[str, int] = {}
    for index, robot_id in enumerate(ids):
        if robot_id in first:
            raise InvalidInput(
                f"robots[{index}].id: {robot_id!r} is already the id of robots[{first[robot_id]}].",
                field=f"robots[{index}].id",
            )
        first[robot_id] = index


def _validate_task(data: object) -> Task:
    try:
        return Task.model_validate(data)
    except ValidationError as error:
        raise describe_validation_errors(error.errors(), "task") from None


def _reject_constant(name: str) -> NoReturn:
    # Python's json takes NaN and Infinity; JSON does not.
    raise InvalidInput(f"the input is not valid JSON: {name} is not a JSON number.")


def _json_type(value: Any) -> str:
    if isinstance(value, list):
        return "an array"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, bool):
        return "a boolean"
    if value is None:
        return "null"
    return "a number"


# --- the columnar reader ---------------------------------------------------------

class _Document(msgspec.Struct, forbid_unknown_fields=True):
    robots: list[msgspec.Raw]
    task: msgspec.Raw


@dataclass(frozen=True)
class Candidates:
    """What the selection needs of a scenario: the task and the robots that pass its filter.

    ``robots`` are the candidates in file order (``filter_robots`` of all the
    robots); ``total`` is how many robots the document held. ``reading_ms``
    and ``filtering_ms`` say where the reader's time went; ``reader`` is
    ``columnar``, or ``objects`` when the document went to the objects reader.
    """

    robots: list[RobotLike]
    task: Task
    total: int
    reading_ms: float
    filtering_ms: float
    reader: Literal["columnar", "objects"]


class _UseObjects(Exception):
    """msgspec and pydantic disagree, or msgspec cannot split the document."""


def read_candidates(data: bytes | str, source: str = "the input") -> Candidates:
    """Validate ``data`` as :func:`parse_select_input` does and keep the candidates.

    The same document gives the same candidates (``filter_robots`` of the
    validated robots) and the same task, or the same error sentence.
    """
    started = time.perf_counter()
    try:
        return _read_columns(data, started)
    except _UseObjects:
        pass
    text = data if isinstance(data, str) else decode_text(data, source)
    robots, task = parse_select_input(text, source)
    read = time.perf_counter()
    candidates: list[RobotLike] = list(filter_robots(robots, task))
    return Candidates(
        robots=candidates,
        task=task,
        total=len(robots),
        reading_ms=(read - started) * 1000.0,
        filtering_ms=(time.perf_counter() - read) * 1000.0,
        reader="objects",
    )


def decode_text(data: bytes, source: str) -> str:
    """``data`` as text, its newlines as a text-mode read gives them."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise InvalidInput(f"{source} is not UTF-8 text ({error.reason}).") from None
    return text.replace("\r\n", "\n").replace("\r", "\n")


def _read_columns(data: bytes | str, started: float) -> Candidates:
    try:
        document = msgspec.json.decode(data, type=_Document)
    except (msgspec.DecodeError, msgspec.ValidationError):
        # Not JSON, not an object, a field missing or unknown: the objects
        # reader finds it (in its own words) before it builds any robot.
        raise _UseObjects from None
    task_error: InvalidInput | None = None
    task: Task | None = None
    try:
        task = _validate_task(json.loads(bytes(document.task)))
    except InvalidInput as error:  # said after the robots' errors, as the objects reader does
        task_error = error
    raw = document.robots
    del document
    may_escape = may_hold_control_characters(data)
    record: type[RobotRecord] = CheckedRobotRecord if may_escape else RobotRecord
    decoder: msgspec.json.Decoder[list[CheckedRobotRecord]] | msgspec.json.Decoder[
        list[RobotRecord]
    ] = (
        msgspec.json.Decoder(list[CheckedRobotRecord])
        if may_escape
        else msgspec.json.Decoder(list[RobotRecord])
    )
    ids: list[str] = []
    candidates: list[RobotLike] = []
    filtering = 0.0
    for start in range(0, len(raw), CHUNK):
        try:
            piece = decoder.decode(b"[" + b",".join(raw[start : start + CHUNK]) + b"]")
        except msgspec.ValidationError:
            raise _robot_errors(raw, start, record) from None
        except msgspec.DecodeError:
            raise _UseObjects from None
        ids += [robot.id for robot in piece]
        if task is not None:
            before = time.perf_counter()
            candidates += filter_robots(piece, task)
            filtering += time.perf_counter() - before
    if task_error is not None:
        raise task_error
    assert task is not None
    if len(set(ids)) != len(ids):
        check_unique_ids(ids)
    total_ms = (time.perf_counter() - started) * 1000.0
    return Candidates(
        robots=candidates,
        task=task,
        total=len(ids),
        reading_ms=total_ms - filtering * 1000.0,
        filtering_ms=filtering * 1000.0,
        reader="columnar",
    )


def _robot_errors(raw: list[msgspec.Raw], start: int, record: type[RobotRecord]) -> InvalidInput:
    """The objects reader's sentence for the robots from ``start`` on (those before are valid).

    Every robot msgspec refuses is validated by pydantic, whose errors make
    the sentence; a robot msgspec refuses and pydantic takes means the two
    disagree, and the objects reader answers instead.
    """
    one = msgspec.json.Decoder(record)
    errors: list[dict[str, Any]] = []
    for index in range(start, len(raw)):
        try:
            one.decode(raw[index])
        except msgspec.ValidationError:
            try:
                value = json.loads(bytes(raw[index]))
            except ValueError:
                raise _UseObjects from None
            try:
                Robot.model_validate(value)
            except ValidationError as error:
                errors += [{**e, "loc": (index, *e["loc"])} for e in error.errors()]
                continue
            raise _UseObjects from None
        except msgspec.DecodeError:
            raise _UseObjects from None
    if not errors:
        raise _UseObjects
    return describe_validation_errors(errors, "robots")
