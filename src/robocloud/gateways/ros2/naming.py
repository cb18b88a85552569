"""Where a robot's ROS 2 names are on Zenoh, and the attachment rmw_zenoh adds to each message.

Two schemes (docs/ros2.md):

- ``rmw_zenoh`` (ros2/rmw_zenoh, docs/design.md): a topic or service is the
  key ``<domain>/<fully qualified name>/<DDS type name>/<type hash>`` (the
  hash is ``RIHS01_<64 hex>`` from Iron on, ``TypeHashNotSupported`` on
  Humble); each entity also holds a liveliness token
  ``@ros2_lv/<domain>/<session>/<node>/<entity>/<kind>/<enclave>/<namespace>/
  <node name>/<mangled name>/<type>/<hash>/<qos>`` (a mangled name has each
  ``/`` as ``%``); every message and request carries an attachment.
- ``bridge`` (zenoh-bridge-ros2dds): the key is the name without its leading
  ``/``, under the bridge's namespace; no type, no hash, no attachment.

An action ``A`` is the services ``A/_action/send_goal``, ``.../get_result``,
``.../cancel_goal`` and the topics ``A/_action/feedback`` and ``.../status``.

The attachment (rmw_zenoh since April 2025, 33 bytes, little-endian): the
sequence number (int64), the source timestamp (int64, ns since the epoch),
the GID's length (one byte, 16) and the GID. Older robots send the same three
values in zenoh-ext's serialization with their names before them
(``"sequence_number"``, ``"source_timestamp"``, ``"source_gid"``); both are
read, only the current form is written.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from robocloud.gateways.ros2.interfaces import DDS_NAMES

LIVELINESS = "@ros2_lv"
NO_HASH = "TypeHashNotSupported"
ATTACHMENT_SIZE = 33
GID_SIZE = 16
SERVICES = ("send_goal", "get_result", "cancel_goal")
ACTION_TOPICS = ("feedback", "status")
ENTITY_KINDS = {"SS": "service server", "MP": "publisher", "SC": "client", "MS": "subscription"}


class AttachmentError(ValueError):
    """An attachment that is neither of rmw_zenoh's forms."""


@dataclass(frozen=True)
class Attachment:
    sequence_number: int
    source_timestamp: int  # ns since the epoch
    gid: bytes

    def encode(self) -> bytes:
        """The current form: 33 bytes."""
        return struct.pack(
            "<qqB16s", self.sequence_number, self.source_timestamp, GID_SIZE, self.gid
        )


def decode_attachment(raw: bytes) -> Attachment:
    """Either form; ``AttachmentError`` for anything else."""
    if len(raw) == ATTACHMENT_SIZE:
        seq, stamp, size, gid = struct.unpack("<qqB16s", raw)
        if size != GID_SIZE:
            raise AttachmentError(f"the GID length byte is {size}, not {GID_SIZE}")
        return Attachment(seq, stamp, gid)
    return _decode_keyed(raw)


def _decode_keyed(raw: bytes) -> Attachment:
    """The pre-2025 form: name, value, name, value, name, GID (zenoh-ext serialization)."""
    pos = 0

    def name() -> str:
        nonlocal pos
        size, pos = _varint(raw, pos)
        text = raw[pos : pos + size]
        pos += size
        return text.decode("utf-8", "replace")

    def int64() -> int:
        nonlocal pos
        if pos + 8 > len(raw):
            raise AttachmentError("it ends inside a number")
        (value,) = struct.unpack_from("<q", raw, pos)
        pos += 8
        return int(value)

    values: dict[str, int | bytes] = {}
    try:
        for expected in ("sequence_number", "source_timestamp"):
            if name() != expected:
                raise AttachmentError(f"it is {len(raw)} bytes and has no {expected}")
            values[expected] = int64()
        if name() != "source_gid":
            raise AttachmentError("it has no source_gid")
        left = len(raw) - pos
        if left == GID_SIZE + 1 and raw[pos] == GID_SIZE:  # a sequence: its length first
            pos += 1
        elif left != GID_SIZE:
            raise AttachmentError(f"its GID is {left} bytes, not {GID_SIZE}")
        gid = raw[pos : pos + GID_SIZE]
    except IndexError:
        raise AttachmentError("it ends early") from None
    seq, stamp = values["sequence_number"], values["source_timestamp"]
    assert isinstance(seq, int) and isinstance(stamp, int)
    return Attachment(seq, stamp, bytes(gid))


def _varint(raw: bytes, pos: int) -> tuple[int, int]:
    value, shift = 0, 0
    while True:
        byte = raw[pos]
        pos += 1
        value |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return value, pos
        shift += 7
        if shift > 28:
            raise AttachmentError("a length is too long")


def encode_keyed_attachment(attachment: Attachment) -> bytes:
    """The pre-2025 form (the stand-in speaks it when told to be an older robot)."""
    out = bytearray()
    for key, value in (
        ("sequence_number", attachment.sequence_number),
        ("source_timestamp", attachment.source_timestamp),
    ):
        out += bytes([len(key)]) + key.encode() + struct.pack("<q", value)
    out += bytes([len("source_gid")]) + b"source_gid" + bytes([GID_SIZE]) + attachment.gid
    return bytes(out)


# -- names ---------------------------------------------------------------------------


def namespace_parts(namespace: str) -> list[str]:
    return [part for part in namespace.strip("/").split("/") if part]


def full_name(namespace: str, name: str) -> str:
    """The fully qualified name without its leading ``/``: ``bot1/navigate_to_pose``."""
    return "/".join([*namespace_parts(namespace), *name.strip("/").split("/")])


def action_entity(action: str, what: str) -> str:
    """The name of one of an action's services or topics: ``navigate_to_pose/_action/status``."""
    return f"{action.strip('/')}/_action/{what}"


def bridge_key(namespace: str, name: str) -> str:
    return full_name(namespace, name)


def rmw_key(domain: int, namespace: str, name: str, dds_type: str, type_hash: str) -> str:
    return f"{domain}/{full_name(namespace, name)}/{dds_type}/{type_hash}"


def rmw_subscription_key(domain: int, namespace: str, name: str) -> str:
    """Every type and hash of a topic: the type is checked per sample, the hash at the token."""
    return f"{domain}/{full_name(namespace, name)}/*/*"


def mangle(name: str) -> str:
    return "%" + name.strip("/").replace("/", "%") if name.strip("/") else "%"


@dataclass(frozen=True)
class Token:
    """An rmw_zenoh entity's liveliness token, the part the gateway reads."""

    domain: int
    session: str
    kind: str  # NN, MP, MS, SS, SC
    namespace: str  # "/bot1", or "" for none
    node: str
    name: str  # fully qualified, without the leading "/"; "" for a node
    dds_type: str
    type_hash: str


def parse_token(key: str) -> Token | None:
    """The token of ``key``, or None when it is not one rmw_zenoh would declare."""
    parts = key.split("/")
    if len(parts) < 9 or parts[0] != LIVELINESS or not parts[1].isdigit():
        return None
    kind = parts[5]
    namespace = "" if parts[7] == "%" else parts[7].replace("%", "/")
    if kind == "NN":
        return Token(int(parts[1]), parts[2], kind, namespace, parts[8], "", "", "")
    if len(parts) < 13 or kind not in ENTITY_KINDS:
        return None
    name = parts[9].replace("%", "/").strip("/")
    return Token(int(parts[1]), parts[2], kind, namespace, parts[8], name, parts[10], parts[11])


def token_key(
    domain: int,
    session: str,
    node_id: int,
    entity_id: int,
    kind: str,
    namespace: str,
    node: str,
    name: str = "",
    dds_type: str = "",
    type_hash: str = "",
    qos: str = "::,10:,:,:,,",
) -> str:
    """The liveliness token rmw_zenoh declares for an entity (the stand-in robot's)."""
    ns = "%" if not namespace_parts(namespace) else mangle(namespace)
    head = f"{LIVELINESS}/{domain}/{session}/{node_id}/{entity_id}/{kind}/%/{ns}/{node}"
    if kind == "NN":
        return head
    return f"{head}/{mangle(name)}/{dds_type}/{type_hash}/{qos}"


def expected_type(what: str) -> str:
    """The DDS type name of one of the action's parts, or of ``tf`` and ``battery``."""
    return DDS_NAMES[what]
