"""Log lines that cannot be forged: every control character of a message is escaped.

A name, a key or a sentence a robot or another cloud sent may reach a log
line. Written raw, ``"\\n2026-12-02 04:30:00,000 cloud-a WARNING ...: cloud-b is
back"`` would make a second, convincing line; ``\\r`` would overwrite one on a
terminal, and a bidirectional override (U+202E) would make a line read
otherwise than it is written. ``install`` escapes them in every record this
process makes, whichever logger and handler: C0 and C1 controls, DEL, the
Unicode line and paragraph separators and the bidirectional overrides
become ``\\n``, ``\\x1b``, ``\\u202e``. A traceback (``exc_info``) is left as
it is: its lines are Python's.

``robocloud.cli.exits.run``, through which every command runs, installs it
first, so every command's log (the IaaS, the simulator, the gateways, the
wildfire server) is covered wherever it configures its handlers.
"""

from __future__ import annotations

import logging
import re
from typing import Any

_UNSAFE = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029\u202a-\u202e\u2066-\u2069]")
_NAMED = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}


def _escaped(match: re.Match[str]) -> str:
    char = match.group()
    named = _NAMED.get(char)
    if named is not None:
        return named
    code = ord(char)
    return f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}"


def escape(text: str) -> str:
    """``text`` with every character that could forge or hide a log line escaped."""
    return _UNSAFE.sub(_escaped, text)


class EscapeControls(logging.Filter):
    """Escapes the control characters of a record's message (``escape``); never drops one."""

    def filter(self, record: logging.LogRecord) -> bool:
        try:
            message = record.getMessage()
        except Exception:  # a bad format string: logging itself reports it later
            return True
        if _UNSAFE.search(message):
            record.msg, record.args = escape(message), None
        return True


_FILTER = EscapeControls()
_installed = False


def install() -> None:
    """Escape every log record this process makes from now on (once; repeating is harmless).

    Through the record factory rather than a handler's filter: records
    reach handlers that robocloud did not make (uvicorn's, a library's), and
    a filter on a logger misses what its children propagate.
    """
    global _installed
    if _installed:
        return
    make = logging.getLogRecordFactory()

    def escaping(*args: Any, **kwargs: Any) -> logging.LogRecord:
        record = make(*args, **kwargs)
        _FILTER.filter(record)
        return record

    logging.setLogRecordFactory(escaping)
    _installed = True
