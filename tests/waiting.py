"""Waiting on an event in a test: ask until the answer holds, or fail saying what was awaited.

The one way tests wait (no sleeps as synchronisation): ``wait_until(check,
timeout, what)`` calls ``check`` every ``every`` seconds and returns its first
true answer; past ``timeout`` it fails the test with "timed out after ... s
waiting for <what>".
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")


def wait_until(
    check: Callable[[], T],
    timeout: float = 5.0,
    what: str = "the condition to hold",
    every: float = 0.02,
    ignore: tuple[type[BaseException], ...] = (),
) -> T:
    """``check()``'s first true answer within ``timeout`` seconds; ``ignore``: errors
    that count as a false answer (e.g. a server not listening yet)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            value = check()
        except ignore:
            value = None  # type: ignore[assignment]
        if value:
            return value
        if time.monotonic() >= deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(every)

