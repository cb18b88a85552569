"""Helpers for tests that use real Zenoh sessions on loopback."""

from __future__ import annotations

import zenoh

from waiting import wait_until


def until_subscribed(session: zenoh.Session, key: str, timeout: float = 5.0) -> None:
    """Wait until a subscriber for ``key`` is known to ``session`` (the event, not a sleep)."""
    publisher = session.declare_publisher(key)
    try:
        wait_until(lambda: publisher.matching_status.matching, timeout, f"a subscriber for {key}")
    finally:
        publisher.undeclare()  # type: ignore[no-untyped-call]
