"""The link to one brick: framed telegrams over a stream socket, behind one seam.

- a real brick: Bluetooth RFCOMM, channel 1 (``socket.AF_BLUETOOTH``, Linux);
- a stand-in brick (``standin.py``): TCP, with exactly the same framing.

USB is not spoken (an NXT on USB uses bulk endpoints, not a stream socket).
``Link`` is the seam the driver uses; ``SocketLink`` is the one there is, and
tests may give the driver another.
"""

from __future__ import annotations

import contextlib
import socket
from typing import Protocol

from robocloud.gateways.nxt.telegrams import TelegramError, frame, frame_length

RFCOMM_CHANNEL = 1  # the NXT's serial port profile


class LinkDown(OSError):
    """The brick did not answer in time, or the connection broke."""


class Link(Protocol):
    def exchange(self, telegram: bytes) -> bytes:
        """Send a telegram that wants a reply and return the reply (LinkDown if none)."""
        ...

    def send(self, telegram: bytes) -> None:
        """Send a telegram that wants no reply."""
        ...

    def close(self) -> None: ...


class SocketLink:
    """Framed telegrams over a connected stream socket; every read waits at most ``timeout``."""

    def __init__(self, sock: socket.socket, timeout: float) -> None:
        self._sock = sock
        self._sock.settimeout(timeout)

    def exchange(self, telegram: bytes) -> bytes:
        self.send(telegram)
        try:
            length = frame_length(self._read(2))
        except TelegramError as error:
            raise LinkDown(str(error)) from None
        return self._read(length)

    def send(self, telegram: bytes) -> None:
        try:
            self._sock.sendall(frame(telegram))
        except OSError as error:
            raise LinkDown(f"sending failed: {error.strerror or error}") from None

    def _read(self, count: int) -> bytes:
        data = b""
        while len(data) < count:
            try:
                chunk = self._sock.recv(count - len(data))
            except TimeoutError:
                raise LinkDown("the brick did not answer in time") from None
            except OSError as error:
                raise LinkDown(f"reading failed: {error.strerror or error}") from None
            if not chunk:
                raise LinkDown("the brick closed the connection")
            data += chunk
        return data

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._sock.close()


def connect_tcp(host: str, port: int, timeout: float) -> SocketLink:
    try:
        sock = socket.create_connection((host, port), timeout=timeout)
    except OSError as error:
        raise LinkDown(f"cannot connect to {host}:{port}: {error.strerror or error}") from None
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return SocketLink(sock, timeout)


def connect_rfcomm(address: str, timeout: float, channel: int = RFCOMM_CHANNEL) -> SocketLink:
    """A Bluetooth RFCOMM link to a paired brick (Linux; Python's socket module has it)."""
    family = getattr(socket, "AF_BLUETOOTH", None)
    proto = getattr(socket, "BTPROTO_RFCOMM", None)
    if family is None or proto is None:
        raise LinkDown("this Python has no Bluetooth sockets (AF_BLUETOOTH): Linux with BlueZ")
    try:
        sock = socket.socket(family, socket.SOCK_STREAM, proto)
    except OSError as error:
        raise LinkDown(f"cannot open a Bluetooth socket: {error.strerror or error}") from None
    sock.settimeout(max(timeout, 5.0))  # a Bluetooth connect takes seconds
    try:
        sock.connect((address, channel))
    except OSError as error:
        sock.close()
        raise LinkDown(f"cannot connect to {address}: {error.strerror or error}") from None
    return SocketLink(sock, timeout)
