"""The gateway's CDR codec: ROS 2 messages from their ``.msg`` text, read and written as dicts.

ROS 2 carries messages as plain CDR (XCDR1, OMG DDS-XTypes 7.4.1.1): a
4-byte encapsulation header (``00 01`` little-endian, ``00 00`` big-endian,
then two option bytes), then the fields in order, each primitive aligned to
its size (at most 8) counted from the end of the header; a string is a
``uint32`` length counting its NUL, its bytes and the NUL; a sequence a
``uint32`` count and its elements; a fixed array its elements alone.

Reading is strict: a message must end where its type ends, give or take the
3 bytes of padding a writer may add, unless the caller allows a longer one
(a newer distro's extension). Anything else is ``CdrError`` with a sentence.
The stand-in robot (``standin.py``) encodes with pycdr2 instead, so each
checks the other.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

PRIMITIVES: dict[str, str] = {
    "bool": "?", "byte": "B", "char": "B", "uint8": "B", "int8": "b",
    "uint16": "H", "int16": "h", "uint32": "I", "int32": "i",
    "uint64": "Q", "int64": "q", "float32": "f", "float64": "d",
}  # fmt: skip
MAX_LENGTH = 1 << 20  # elements of one sequence, bytes of one string: a bound on a bad message


class CdrError(ValueError):
    """A message that does not decode as its type (or a value that does not encode)."""


@dataclass(frozen=True)
class Field:
    name: str
    type: str  # a primitive, "string" or a type's name
    array: int | None  # None: one value; -1: a sequence; n: a fixed array of n


class Codec:
    """Messages of the types in ``definitions`` (name -> ``.msg`` text)."""

    def __init__(self, definitions: Mapping[str, str]) -> None:
        self._types = {name: _parse(name, text) for name, text in definitions.items()}
        for name, fields in self._types.items():
            for f in fields:
                if f.type not in PRIMITIVES and f.type != "string" and f.type not in self._types:
                    raise ValueError(f"{name}.{f.name}: unknown type {f.type}")

    def encode(self, typename: str, value: Mapping[str, Any]) -> bytes:
        out = bytearray(b"\x00\x01\x00\x00")
        try:
            self._write(out, typename, value)
        except (struct.error, KeyError, TypeError) as error:
            raise CdrError(f"{typename} cannot be encoded: {error}") from None
        return bytes(out)

    def decode(self, typename: str, data: bytes, *, trailing: bool = False) -> dict[str, Any]:
        if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
            raise CdrError(f"{typename}: not CDR (no encapsulation header)")
        reader = _Reader(memoryview(data)[4:], "<" if data[1] else ">")
        try:
            value = self._read(reader, typename)
        except (struct.error, UnicodeDecodeError) as error:
            raise CdrError(f"{typename} does not decode: {error}") from None
        left = len(reader.data) - reader.pos
        if left > 3 and not trailing:
            raise CdrError(f"{typename} has {left} bytes more than its type")
        return value

    # -- writing --------------------------------------------------------------------

    def _write(self, out: bytearray, typename: str, value: Mapping[str, Any]) -> None:
        for f in self._types[typename]:
            v = value[f.name]
            if f.array is None:
                self._write_one(out, f.type, v)
                continue
            items = list(v)
            if f.array >= 0 and len(items) != f.array:
                raise CdrError(f"{typename}.{f.name} needs {f.array} elements, not {len(items)}")
            if f.array < 0:
                _align(out, 4)
                out += struct.pack("<I", len(items))
            for item in items:
                self._write_one(out, f.type, item)

    def _write_one(self, out: bytearray, type_: str, value: Any) -> None:
        code = PRIMITIVES.get(type_)
        if code is not None:
            size = struct.calcsize(code)
            _align(out, size)
            out += struct.pack("<" + code, value)
        elif type_ == "string":
            raw = str(value).encode()
            _align(out, 4)
            out += struct.pack("<I", len(raw) + 1) + raw + b"\x00"
        else:
            self._write(out, type_, value)

    # -- reading --------------------------------------------------------------------

    def _read(self, reader: _Reader, typename: str) -> dict[str, Any]:
        value: dict[str, Any] = {}
        for f in self._types[typename]:
            if f.array is None:
                value[f.name] = self._read_one(reader, f.type)
                continue
            count = f.array if f.array >= 0 else reader.length()
            value[f.name] = [self._read_one(reader, f.type) for _ in range(count)]
        return value

    def _read_one(self, reader: _Reader, type_: str) -> Any:
        code = PRIMITIVES.get(type_)
        if code is not None:
            return reader.primitive(code)
        if type_ == "string":
            size = reader.length()
            if size == 0:
                return ""  # some writers send an empty string as length 0
            raw = reader.take(size)
            if raw[-1] != 0:
                raise CdrError("a string does not end with NUL")
            return bytes(raw[:-1]).decode()
        return self._read(reader, type_)


class _Reader:
    def __init__(self, data: memoryview, order: str) -> None:
        self.data, self.order, self.pos = data, order, 0

    def primitive(self, code: str) -> Any:
        size = struct.calcsize(code)
        self.pos += -self.pos % size
        (value,) = struct.unpack_from(self.order + code, self.data, self.pos)
        self.pos += size
        return value

    def length(self) -> int:
        n: int = self.primitive("I")
        if n > MAX_LENGTH or n > len(self.data) - self.pos:
            raise CdrError(f"a length of {n} runs past the message")
        return n

    def take(self, n: int) -> memoryview:
        if self.pos + n > len(self.data):
            raise CdrError("the message ends early")
        raw = self.data[self.pos : self.pos + n]
        self.pos += n
        return raw


def _align(out: bytearray, size: int) -> None:
    out += b"\x00" * (-(len(out) - 4) % size)


def _parse(name: str, text: str) -> list[Field]:
    package = name.split("/")[0]
    fields = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line or "=" in line:  # a blank line, a comment, a constant
            continue
        type_, field_name = line.split()[:2]
        array: int | None = None
        if type_.endswith("]"):
            type_, size = type_[:-1].split("[")
            array = int(size) if size else -1
        if type_ not in PRIMITIVES and type_ != "string" and "/" not in type_:
            type_ = f"{package}/{type_}"
        fields.append(Field(field_name, type_, array))
    return fields
