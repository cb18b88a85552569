"""What the store gives back: a request with its history, as frozen records.

These are stored rows, not wire models; the API layer has its own Pydantic
classes and builds them from these.
"""

from __future__ import annotations

import base64
import secrets
from dataclasses import dataclass
from datetime import datetime
from typing import Any, Literal

HistoryKind = Literal["state", "event"]


@dataclass(frozen=True)
class StateChange:
    """One line of a request's history.

    ``kind="state"``: the request moved to ``state``. ``kind="event"``: something
    happened while it stayed in ``state`` ("robot a-0003 failed; replaced by
    a-0017"); ``detail`` says what.
    """

    state: str
    at: datetime
    detail: str | None = None
    kind: HistoryKind = "state"


@dataclass(frozen=True)
class RequestRecord:
    """A stored request.

    ``task`` is the task JSON as the application gave it; ``selection`` is the
    chosen coalition and how it was found, opaque JSON to the store. ``reason``
    says why the request is in its state when that needs saying (rejected,
    failed). ``history`` is oldest first and starts with ``received``.
    """

    id: str
    application: str
    label: str | None
    task: dict[str, Any]
    state: str
    reason: str | None
    created_at: datetime
    updated_at: datetime
    selection: dict[str, Any] | None
    idempotency_key: str | None
    history: tuple[StateChange, ...]


def new_request_id() -> str:
    """``req-`` and 12 lower-case base32 characters (60 random bits): short, URL-safe."""
    return "req-" + base64.b32encode(secrets.token_bytes(8)).decode("ascii")[:12].lower()
