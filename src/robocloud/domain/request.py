"""A request's life cycle: the states of ARCHITECTURE.md and the moves between them.

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
