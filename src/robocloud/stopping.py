"""Commands that run until told to stop: SIGINT or SIGTERM set an event.

The simulator and the gateways run until Ctrl-C or SIGTERM, then stop
cleanly (their robots told, their sessions closed); ``stop_on_signals`` is
how each of them hears it.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator


@contextlib.contextmanager
def stop_on_signals() -> Iterator[threading.Event]:
    """An event that SIGINT and SIGTERM set while the block runs.

    Handlers are installed only on the main thread (Python allows no other;
    a command run on another thread, as in a test, is stopped by setting the
    event). The previous handlers are back once the block ends.
    """
    stop = threading.Event()
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for signum in (signal.SIGINT, signal.SIGTERM):
            previous[signum] = signal.signal(signum, lambda *_: stop.set())
    try:
        yield stop
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
