"""A request's life cycle: the states of docs/architecture.md and the moves between them.

::

    received -> selecting -> dispatched -> underway -> completed
                    |             |            |
                    v             v            v
                 rejected       failed       failed
    (any state before completed, rejected or failed) -> canceled

A request that is underway stays underway while a failed robot is replaced;
the history records the replacement.
"""

from __future__ import annotations

from typing import Literal

from robocloud.errors import explained

# An Idempotency-Key, as the IaaS takes it and the wildfire server passes it on.
IDEMPOTENCY_KEY_RULE = "1 to 200 printable characters without spaces"
IDEMPOTENCY_KEY_PATTERN = explained(r"^[\x21-\x7e]{1,200}$", IDEMPOTENCY_KEY_RULE)

RequestState = Literal[
    "received",
    "selecting",
    "dispatched",
    "underway",
    "completed",
    "rejected",
    "canceled",
    "failed",
]
REQUEST_STATES: tuple[RequestState, ...] = (
    "received",
    "selecting",
    "dispatched",
    "underway",
    "completed",
    "rejected",
    "canceled",
    "failed",
)
FINAL_STATES: frozenset[str] = frozenset({"completed", "rejected", "canceled", "failed"})
ACTIVE_STATES: frozenset[str] = frozenset({"received", "selecting", "dispatched", "underway"})

_MOVES: dict[str, frozenset[str]] = {
    "received": frozenset({"selecting", "canceled", "failed"}),
    "selecting": frozenset({"dispatched", "rejected", "canceled", "failed"}),
    "dispatched": frozenset({"underway", "completed", "canceled", "failed"}),
    "underway": frozenset({"underway", "completed", "canceled", "failed"}),
}


def can_move(current: str, new: str) -> bool:
    """Whether a request in ``current`` may move to ``new``."""
    return new in _MOVES.get(current, frozenset())


def is_final(state: str) -> bool:
    return state in FINAL_STATES
