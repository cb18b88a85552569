"""JSON bodies read strictly: an object that repeats a key is refused, the key named.

RFC 8259 (section 4) says the names of an object SHOULD be unique and that
readers disagree on an object that repeats one: Python's ``json`` and pydantic
keep the last value, other parsers the first or an error. So
``{"max_robots": 1, "max_robots": 5}`` would mean 5 here and maybe 1 to a proxy
or an auditor that read the same bytes. Every JSON body robocloud's HTTP
servers take is checked here first (the IaaS's ``Gate``, ``robocloud.iaas.app``):
the answer is a 422 naming the key, e.g. ``max_robots: the key 'max_robots' is
given more than once; give each key once.``

Only repeated keys are judged here; a body that is not JSON at all is left to
the route's own reader, whose sentences say so.
"""

from __future__ import annotations

import json
from typing import Any

from robocloud.errors import InvalidInput


class _Pairs(list[tuple[str, Any]]):
    """An object as the parser saw it: its (key, value) pairs in order, repeats kept."""


def repeated_key(body: bytes | str) -> InvalidInput | None:
    """The 422 for the first key an object of ``body`` repeats, or None.

    None too for a body that is not JSON (or is nested too deep to read):
    the reader that follows refuses it with its own sentence.
    """
    try:
        parsed = json.loads(body, object_pairs_hook=_Pairs)
    except (ValueError, RecursionError):
        return None
    found = _first_repeat(parsed, "")
    if found is None:
        return None
    path, key = found
    return InvalidInput(
        f"{path}: the key {key!r} is given more than once; give each key once.", path
    )


def _first_repeat(value: Any, where: str) -> tuple[str, str] | None:
    """(path, key) of the first repeated key in ``value``, depth first, in order."""
    stack: list[tuple[Any, str]] = [(value, where)]
    while stack:
        item, path = stack.pop()
        if isinstance(item, _Pairs):
            seen: set[str] = set()
            for key, _ in item:
                if key in seen:
                    return (f"{path}.{key}" if path else key), key
                seen.add(key)
            stack.extend(
                (child, f"{path}.{key}" if path else key) for key, child in reversed(item)
            )
        elif isinstance(item, list):
            stack.extend((child, f"{path}[{i}]") for i, child in reversed(list(enumerate(item))))
    return None
