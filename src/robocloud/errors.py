"""The errors a user of robocloud can cause, in one family.

::

    RoboCloudError                  a sentence for the user, never a traceback
    ├── InvalidInput                bad JSON, a missing field, a wrong value   (HTTP 422, exit 2)
    │   └── PayloadTooLarge         a body over the size limit                 (HTTP 413, exit 2)
    ├── NotFound                    no such file, request or robot             (HTTP 404, exit 2)
    ├── Unauthorized                a missing or wrong API key                 (HTTP 401)
    ├── Conflict                    the action does not fit the current state  (HTTP 409)
    └── Unavailable                 a part it needs is down; try again later   (HTTP 503)
        ├── StoreUnavailable        the database (robocloud.storage)
        └── Busy                    the cloud has more requests waiting than it can decide in time

Each error carries its context (the field, the id) besides its sentence.
HTTP status codes are mapped in ``robocloud.iaas`` and exit codes in
``robocloud.cli``, each in one place.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any


class RoboCloudError(Exception):
    """Base of every error a user can cause; ``str(error)`` is the sentence."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


class InvalidInput(RoboCloudError):
    """Input that does not match docs/model.md's shapes or rules."""

    def __init__(self, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.field = field


class PayloadTooLarge(InvalidInput):
    pass


class NotFound(RoboCloudError):
    def __init__(self, message: str, key: str | None = None) -> None:
        super().__init__(message)
        self.key = key


class Unauthorized(RoboCloudError):
    pass


class Conflict(RoboCloudError):
    pass


class Unavailable(RoboCloudError):
    """Something robocloud needs cannot be reached now; the same call may work later."""

    def __init__(self, message: str, retry_after: float = 5.0) -> None:
        super().__init__(message)
        self.retry_after = retry_after


class Busy(Unavailable):
    """The IaaS refuses a new request while it is behind with the ones it has (load shedding).

    Its 503 carries ``HEADER: 1``: nothing was stored, so a client may send the
    same request to another cloud at once (another 503 may have stored it).
    """

    HEADER = "X-Robocloud-Busy"

    def __init__(self, message: str, retry_after: float = 1.0) -> None:
        super().__init__(message, retry_after)


# What a field's pattern allows, in words (``explained``): a value it refuses is
# told that, not shown a regular expression.
_PATTERN_WORDS: dict[str, str] = {}


def explained(pattern: str, words: str) -> str:
    """``pattern``, noted with what it allows in words, for ``describe_validation_errors``."""
    _PATTERN_WORDS[pattern] = words
    return pattern


def field_path(location: Iterable[int | str], prefix: str = "") -> str:
    """``("robots", 3, "speed")`` -> ``robots[3].speed``."""
    path = prefix
    for part in location:
        if isinstance(part, int):
            path += f"[{part}]"
        else:
            path = f"{path}.{part}" if path else str(part)
    return path or "input"


def describe_validation_errors(
    errors: Iterable[Mapping[str, Any]], prefix: str = ""
) -> InvalidInput:
    """One sentence from pydantic's error list: the first error, named by its field.

    Pydantic's own messages ("Input should be greater than 0") are kept,
    lower-cased into the sentence, so every constraint speaks the same way.
    """
    errors = list(errors)
    first = errors[0]
    # Pydantic puts the model name or the union member in the location of
    # some errors (``function-after[...]``); they mean nothing to a user.
    location = [p for p in first.get("loc", ()) if not (isinstance(p, str) and "[" in p)]
    field = field_path(location, prefix)
    kind = first.get("type", "")
    words = _PATTERN_WORDS.get((first.get("ctx") or {}).get("pattern", ""))
    if kind == "missing":
        text = f"{field} is missing"
    elif kind == "extra_forbidden":
        text = f"{field} is not a known field"
    elif kind in {"json_invalid", "json_type"}:
        text = f"the input is not valid JSON ({first.get('msg', '')})"
    elif kind == "string_pattern_mismatch" and words is not None:
        text = f"{field} must be {words}"
    else:
        msg = str(first.get("msg", "is invalid"))
        msg = msg.removeprefix("Value error, ")
        msg = msg[0].lower() + msg[1:] if msg else "is invalid"
        text = f"{field}: {msg}"
    more = len(errors) - 1
    if more:
        text += f" (and {more} more problem{'s' if more > 1 else ''})"
    return InvalidInput(text.rstrip(".") + ".", field=field)
