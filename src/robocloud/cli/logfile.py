"""The demo's log files: each process's output, kept in files of bounded size.

``make run`` keeps ``var/`` between runs, and a long run used to grow its logs
without bound (issue 26: the wildfire log grew 444 KB in 8 minutes). Each
process writes to a pipe; a thread here copies it, line by line, into
``logging.handlers.RotatingFileHandler``: at most ``MAX_BYTES`` a file, the
file and ``BACKUPS`` older ones (``cloud-a-iaas.log``, ``.log.1`` ... ``.log.3``),
so at most 20 MB a process. A process's tracebacks and prints are lines like
any other, so they land in the file too.
"""

from __future__ import annotations

import logging
import threading
from logging.handlers import RotatingFileHandler
from pathlib import Path
from typing import IO

MAX_BYTES = 5 * 1024 * 1024
BACKUPS = 3


class RotatingLog:
    """One process's log file; ``follow`` copies a stream into it until the stream ends."""

    def __init__(self, path: Path, max_bytes: int = MAX_BYTES, backups: int = BACKUPS) -> None:
        self.path = path
        self._handler = RotatingFileHandler(
            path, maxBytes=max_bytes, backupCount=backups, encoding="utf-8", delay=True
        )
        self._handler.setFormatter(logging.Formatter("%(message)s"))
        self._threads: list[threading.Thread] = []

    def write(self, line: str) -> None:
        # A record of its own per line: the handler rotates between records.
        self._handler.handle(logging.makeLogRecord({"msg": line, "levelno": logging.INFO}))

    def follow(self, stream: IO[bytes], name: str) -> threading.Thread:
        """Copy ``stream`` (a process's stdout) into the file in a thread, until its end."""
        thread = threading.Thread(target=self._copy, args=(stream,), name=name, daemon=True)
        self._threads = [t for t in self._threads if t.is_alive()]
        self._threads.append(thread)
        thread.start()
        return thread

    def _copy(self, stream: IO[bytes]) -> None:
        with stream:
            for raw in stream:
                self.write(raw.rstrip(b"\r\n").decode("utf-8", errors="replace"))

    def close(self, timeout: float = 1.0) -> None:
        """Once its processes have stopped: let the copies finish, then close the file."""
        for thread in self._threads:
            thread.join(timeout)
        self._handler.close()
