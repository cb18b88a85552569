"""The checks and sentences both stores share, so they answer alike.

Every store validates its input here before touching its data, and raises the
same errors with the same sentences; the tests run one suite over all of them.
"""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Callable, Sequence
from datetime import UTC, datetime, timedelta
from typing import Any

from robocloud.domain import FINAL_STATES, REQUEST_STATES, can_move
from robocloud.errors import Conflict, InvalidInput, NotFound

Clock = Callable[[], datetime]

MAX_NAME = 255  # application, idempotency key, robot id: the width of their columns
MAX_PAGE = 1000


def utc_now() -> datetime:
    return datetime.now(UTC)


class StoreClock:
    """The store's clock: UTC, and strictly increasing within one store.

    Strictly increasing so that two requests created back to back are never
    equally new: "newest first" is then the order they were created in.
    ``source`` may be a fake clock in tests (to expire leases without sleeping).
    """

    def __init__(self, source: Clock | None = None) -> None:
        self._source = source or utc_now
        self._last: datetime | None = None
        self._lock = threading.Lock()

    def __call__(self) -> datetime:
        now = self._source()
        if now.tzinfo is None:
            raise ValueError("the store's clock must return timezone-aware datetimes")
        now = now.astimezone(UTC)
        with self._lock:
            if self._last is not None and now <= self._last:
                now = self._last + timedelta(microseconds=1)
            self._last = now
        return now


def dump_json(value: dict[str, Any], what: str) -> str:
    """JSON text for a ``task`` or ``selection``; both databases store it as TEXT."""
    if not isinstance(value, dict):
        raise InvalidInput(f"{what} must be a JSON object, not {type(value).__name__}.", what)
    try:
        return json.dumps(value, allow_nan=False, separators=(",", ":"))
    except (TypeError, ValueError) as error:
        raise InvalidInput(f"{what} is not valid JSON ({error}).", what) from error


def load_json(text: str) -> dict[str, Any]:
    value = json.loads(text)
    assert isinstance(value, dict)
    return value


def check_name(value: str, what: str, field: str) -> str:
    if not isinstance(value, str) or not value or len(value) > MAX_NAME:
        raise InvalidInput(
            f"{what} must be a text of 1 to {MAX_NAME} characters, not {value!r}.", field
        )
    return value


def check_optional_name(value: str | None, what: str, field: str) -> str | None:
    return None if value is None else check_name(value, what, field)


def check_text(value: str | None, field: str) -> str | None:
    """A free text (label, reason, detail) or None."""
    if value is not None and not isinstance(value, str):
        raise InvalidInput(f"{field} must be a text, not {type(value).__name__}.", field)
    return value


def check_state(state: str, field: str = "state") -> str:
    if state not in REQUEST_STATES:
        raise InvalidInput(
            f"{state!r} is not a request state; use one of {', '.join(REQUEST_STATES)}.", field
        )
    return state


def check_transition(
    new_state: str,
    reason: str | None,
    detail: str | None,
    selection: dict[str, Any] | None,
) -> str | None:
    """Check the arguments of ``RequestStore.transition``; the selection as JSON text."""
    check_state(new_state, "new_state")
    check_text(reason, "reason")
    check_text(detail, "detail")
    return None if selection is None else dump_json(selection, "selection")


def check_limit(limit: int) -> int:
    if isinstance(limit, bool) or not isinstance(limit, int) or not 1 <= limit <= MAX_PAGE:
        raise InvalidInput(
            f"limit must be a whole number from 1 to {MAX_PAGE}, not {limit!r}.", "limit"
        )
    return limit


def check_robots(robot_ids: Sequence[str]) -> list[str]:
    """The robot ids, each once, in the order given."""
    return check_names(robot_ids, "a robot id", "robot_ids")


def check_names(values: Sequence[str], what: str, field: str) -> list[str]:
    """Names (robot ids, loan ids), each once, in the order given."""
    if isinstance(values, str):
        raise InvalidInput(f"{field} must be a list of ids, not one text.", field)
    seen: dict[str, None] = {}
    for value in values:
        seen[check_name(value, what, field)] = None
    return list(seen)


def lease_end(now: datetime, lease_seconds: float | None) -> datetime | None:
    """When a lease taken ``now`` expires; None for a firm reservation."""
    if lease_seconds is None:
        return None
    if not math.isfinite(lease_seconds) or lease_seconds <= 0:
        raise InvalidInput(
            f"lease_seconds must be a positive number of seconds, not {lease_seconds!r}.",
            "lease_seconds",
        )
    return now + timedelta(seconds=lease_seconds)


def aware_utc(value: Any) -> datetime | None:
    """A time read with raw SQL (UTC text from SQLite, a datetime from PostgreSQL), aware UTC."""
    if value is None:
        return None
    if isinstance(value, str):
        value = datetime.fromisoformat(value)
    assert isinstance(value, datetime)
    return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


def is_expired(expires_at: datetime | None, now: datetime) -> bool:
    return expires_at is not None and expires_at < now


def no_such_request(request_id: str) -> NotFound:
    return NotFound(f"There is no request {request_id}.", key=request_id)


def bad_cursor(before: str) -> InvalidInput:
    return InvalidInput(
        f"before={before!r} is not a request of this application; "
        "pass the value of next from the previous page.",
        "before",
    )


def check_move(request_id: str, current: str, new: str) -> None:
    if not can_move(current, new):
        if current in FINAL_STATES:
            text = f"Request {request_id} is already {current} and cannot become {new}."
        else:
            text = f"Request {request_id} is {current} and cannot move to {new}."
        raise Conflict(text)


def check_can_hold_robots(request_id: str, state: str) -> None:
    if state in FINAL_STATES:
        raise Conflict(f"Request {request_id} is {state}; it cannot reserve robots.")


def check_lease(lease_seconds: float, now: datetime) -> datetime:
    """When a loan's lease taken ``now`` expires: a loan always starts as a lease."""
    if lease_seconds is None:
        raise InvalidInput("a loan needs lease_seconds: it starts as a lease.", "lease_seconds")
    end = lease_end(now, lease_seconds)
    assert end is not None
    return end


def check_why(why: str) -> str:
    if not isinstance(why, str) or not why.strip():
        raise InvalidInput("why must be a sentence saying why the loans end.", "why")
    return why
