"""What a command reads: a file or stdin, checked, each fault a sentence (``InvalidInput``).

Shared by ``robocloud select``, ``scenario`` and ``plan``.
"""

from __future__ import annotations

import sys
from pathlib import Path

from robocloud.errors import InvalidInput, NotFound

STDIN = "-"


def read_text(source: str) -> str:
    """The file's text, or stdin's for ``-``."""
    if source == STDIN:
        try:
            return sys.stdin.read()
        except UnicodeDecodeError as error:
            raise InvalidInput(f"stdin is not UTF-8 text ({error.reason}).") from None
    path = Path(source)
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise NotFound(f"{source}: no such file.", key=source) from None
    except UnicodeDecodeError as error:
        raise InvalidInput(f"{source} is not UTF-8 text ({error.reason}).") from None
    except OSError as error:
        raise InvalidInput(f"cannot read {source}: {error.strerror or error}.") from None


def read_bytes(source: str) -> bytes | str:
    """The file's bytes, or stdin's for ``-`` (its text when stdin is a text stream
    only, as in tests); the reader checks that they are UTF-8."""
    if source == STDIN:
        buffer = getattr(sys.stdin, "buffer", None)
        if buffer is None:
            return read_text(source)
        data: bytes = buffer.read()
        return data
    try:
        return Path(source).read_bytes()
    except FileNotFoundError:
        raise NotFound(f"{source}: no such file.", key=source) from None
    except OSError as error:
        raise InvalidInput(f"cannot read {source}: {error.strerror or error}.") from None


def source_name(source: str) -> str:
    return "stdin" if source == STDIN else source


def check_at_least(option: str, value: int, least: int) -> None:
    if value < least:
        raise InvalidInput(f"{option} must be at least {least}, not {value}.", field=option)
