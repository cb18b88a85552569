"""Helpers for tests that use real Zenoh sessions on loopback."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable

import zenoh


def free_endpoint() -> str:
    """A loopback TCP endpoint on a port free right now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    return f"tcp/127.0.0.1:{port}"


def until_subscribed(session: zenoh.Session, key: str, timeout: float = 5.0) -> None:
    """Wait until a subscriber for ``key`` is known to ``session`` (the event, not a sleep)."""
    publisher = session.declare_publisher(key)
    try:
        assert wait_until(lambda: publisher.matching_status.matching, timeout), (
            f"no subscriber for {key} reached the session within {timeout} s"
        )
    finally:
        publisher.undeclare()  # type: ignore[no-untyped-call]


def wait_until(predicate: Callable[[], bool], timeout: float = 5.0, every: float = 0.02) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(every)
    return predicate()
