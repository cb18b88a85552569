"""Robots as msgspec decodes them: ``Robot``'s fields and limits, without pydantic objects.

A pydantic ``Robot`` costs about 3 microseconds to validate and build. Where
robots arrive by the hundred or the million (``robocloud select``'s input,
the idle robots another cloud sends for a selection), they are decoded into
these structs instead: msgspec checks the same bounds while it decodes, and
the selection reads them as it reads a ``Robot`` (both are ``RobotLike``).

The names' rule (printable, one line) costs a regular expression per name:
``RobotRecord`` leaves it out, for a document known to hold no escape (JSON
forbids raw control characters in strings, so only an escape can make one);
``CheckedRobotRecord`` keeps it.
"""

from __future__ import annotations

import re
from typing import Annotated, Literal

import msgspec

from robocloud.domain.robot import (
    MAX_AMOUNT,
    MAX_BATTERY,
    MAX_COORDINATE,
    MAX_NAME_LENGTH,
    MAX_SPEED,
    MIN_SPEED,
    NAME_CHARACTERS,
)

# What a name may not hold and JSON lets stand unescaped.
_RAW_REFUSED = re.compile("[\x7f-\x9f\u202a-\u202e\u2066-\u2069]")

# ``Robot``'s limits, as msgspec constraints. A bound also refuses NaN and the
# infinities, as ``allow_inf_nan=False`` does.
RecordName = Annotated[str, msgspec.Meta(min_length=1, max_length=MAX_NAME_LENGTH)]
# The names' pattern, anchored with \Z: Python's $ also matches before a final
# newline, pydantic's (Rust) $ does not.
CheckedName = Annotated[
    str, msgspec.Meta(min_length=1, max_length=MAX_NAME_LENGTH, pattern=rf"^{NAME_CHARACTERS}+\Z")
]
_Amount = Annotated[float, msgspec.Meta(ge=0.0, le=MAX_AMOUNT)]
_Coordinate = Annotated[float, msgspec.Meta(ge=-MAX_COORDINATE, le=MAX_COORDINATE)]
_Speed = Annotated[float, msgspec.Meta(ge=MIN_SPEED, le=MAX_SPEED)]
_Battery = Annotated[float, msgspec.Meta(ge=0.0, le=MAX_BATTERY)]


class CapabilityRecord(msgspec.Struct, forbid_unknown_fields=True, frozen=True, gc=False):
    kind: Literal["sensing", "actuating"]
    time: _Amount
    cost: _Amount


class RobotRecord(msgspec.Struct, forbid_unknown_fields=True, frozen=True, gc=False):
    """A robot as msgspec decodes it: ``Robot``'s fields and limits, a few
    hundred bytes, and no names' pattern (see :class:`CheckedRobotRecord`).

    The position is a tuple: msgspec decodes a length-constrained list about
    three times slower, and the selection only reads it.
    """

    id: RecordName
    cloud: RecordName
    position: tuple[_Coordinate, _Coordinate]
    speed: _Speed
    battery: _Battery
    status: Literal["idle", "reserved", "busy", "charging", "offline"]
    travel_cost_per_m: _Amount
    capabilities: dict[RecordName, CapabilityRecord]


class CheckedRobotRecord(RobotRecord, frozen=True, gc=False):
    """:class:`RobotRecord` with the names' pattern, for documents that may hold one."""

    id: CheckedName
    cloud: CheckedName
    capabilities: dict[CheckedName, CapabilityRecord]


def may_hold_control_characters(document: bytes | str) -> bool:
    """Whether a JSON document may hold a name the names' rule refuses.

    JSON forbids raw C0 control characters in strings, so only an escape (a
    backslash) can make one; DEL, the C1 controls and the bidirectional
    overrides may stand raw. Without any, no name in the document can break
    the rule and ``RobotRecord`` may skip its check.
    """
    if isinstance(document, bytes):
        return (
            b"\\" in document
            or b"\x7f" in document
            or b"\xc2" in document  # C1 controls, U+0080-U+009F, in UTF-8
            or b"\xe2\x80" in document  # U+202A-U+202E
            or b"\xe2\x81" in document  # U+2066-U+2069
        )
    return "\\" in document or _RAW_REFUSED.search(document) is not None
