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


LoanState = Literal["leased", "firm", "released"]
LOAN_STATES: tuple[str, ...] = ("leased", "firm", "released")


@dataclass(frozen=True)
class Loan:
    """One robot of this cloud lent to a request of another cloud (the origin).

    ``leased`` until the origin confirms it (``expires_at`` says when the lease
    lapses; None once the home forwarded the robot's dispatch, after which it
    no longer lapses), then ``firm``, then ``released`` (``reason`` says why).
    ``request_id`` is the origin's id of its request, not a request of this
    store. ``tell_origin``: the home ended the loan on its own (the origin was
    away) and the origin has not been told yet. ``history`` is oldest first.
    """

    id: str
    robot: str
    origin: str
    request_id: str
    state: str
    expires_at: datetime | None
    created_at: datetime
    updated_at: datetime
    reason: str | None
    tell_origin: bool
    history: tuple[StateChange, ...] = ()

    @property
    def active(self) -> bool:
        return self.state != "released"

    def live(self, now: datetime) -> bool:
        """Whether the loan holds its robot at ``now`` (not released, lease not lapsed)."""
        return self.active and (self.expires_at is None or self.expires_at >= now)


def new_loan_id() -> str:
    """``loan-`` and 12 lower-case base32 characters, like request ids."""
    return "loan-" + base64.b32encode(secrets.token_bytes(8)).decode("ascii")[:12].lower()


@dataclass(frozen=True)
class MissionRow:
    """A stored mission: its latest JSON as the API shows it (``document``), opaque
    to the store, and the fields a list or a retry looks it up by."""

    id: str
    application: str
    idempotency_key: str | None
    state: str
    created_at: float  # unix seconds, as the mission's JSON says
    document: dict[str, Any]
