"""``robocloud.json_body``: a JSON body that repeats a key is refused, naming where."""

from __future__ import annotations

import pytest

from robocloud.json_body import repeated_key


@pytest.mark.parametrize(
    ("body", "path"),
    [
        (b'{"max_robots": 1, "max_robots": 5}', "max_robots"),
        (b'{"a": {"b": 1, "c": {"d": 1, "d": 1}}}', "a.c.d"),
        (b'{"a": [{"x": 1}, {"y": 1, "y": 2}]}', "a[1].y"),
        (b'[{"k": 1, "k": 1}]', "[0].k"),
        ('{"é": 1, "é": 2}'.encode(), "é"),
        (b'{"a": {"b": 1, "b": 2}, "a": 3}', "a"),  # the outer repeat is met first
    ],
)
def test_a_repeated_key_is_named_with_its_path(body: bytes, path: str) -> None:
    error = repeated_key(body)
    assert error is not None and error.field == path
    assert error.message.startswith(f"{path}: the key ")
    assert error.message.endswith("is given more than once; give each key once.")


@pytest.mark.parametrize(
    "body",
    [
        b'{"a": 1, "b": {"a": 1}}',  # the same key in two objects is no repeat
        b'[{"a": 1}, {"a": 2}]',
        b"{not json",  # left to the route's reader and its sentence
        b"[" * 50_000 + b"]" * 50_000,
        b"\xff\xfe",
        b'"text"',
    ],
)
def test_bodies_without_a_repeat_pass(body: bytes) -> None:
    assert repeated_key(body) is None
