"""The link to a brick: framed telegrams over a stream socket, and every way it fails."""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterator

import pytest

from robocloud.gateways.nxt.transport import LinkDown, SocketLink, connect_rfcomm, connect_tcp


@pytest.fixture
def pair() -> Iterator[tuple[SocketLink, socket.socket]]:
    ours, brick = socket.socketpair()
    link = SocketLink(ours, timeout=0.3)
    yield link, brick
    link.close()
    brick.close()


def test_a_reply_in_pieces_is_read_whole(pair: tuple[SocketLink, socket.socket]) -> None:
    link, brick = pair

    def answer() -> None:
        assert brick.recv(16) == bytes.fromhex("02 00 00 0B")  # framed GETBATTERYLEVEL
        for piece in (b"\x05", b"\x00\x02\x0b", b"\x00\x78\x1e"):  # length 5, then the reply
            brick.sendall(piece)

    threading.Thread(target=answer).start()
    assert link.exchange(bytes.fromhex("00 0B")) == bytes.fromhex("02 0B 00 78 1E")


def test_silence_is_link_down_in_time(pair: tuple[SocketLink, socket.socket]) -> None:
    link, _brick = pair
    with pytest.raises(LinkDown, match="did not answer in time"):
        link.exchange(bytes.fromhex("00 0B"))


def test_a_closed_connection_is_link_down(pair: tuple[SocketLink, socket.socket]) -> None:
    link, brick = pair
    brick.close()
    with pytest.raises(LinkDown):
        link.exchange(bytes.fromhex("00 0B"))


def test_an_impossible_length_is_link_down(pair: tuple[SocketLink, socket.socket]) -> None:
    link, brick = pair
    brick.sendall(b"\xff\xff")
    with pytest.raises(LinkDown, match="announces 65535 bytes"):
        link.exchange(bytes.fromhex("00 0B"))


def test_nobody_listening_is_a_sentence() -> None:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]  # bound, never listening: refused
        with pytest.raises(LinkDown, match=f"cannot connect to 127.0.0.1:{port}"):
            connect_tcp("127.0.0.1", port, 0.5)


def test_bluetooth_without_an_adapter_is_a_sentence_not_a_crash() -> None:
    # This machine has no Bluetooth adapter (or no Bluetooth sockets at all).
    with pytest.raises(LinkDown, match=r"Bluetooth|00:16:53:0A:1B:2C"):
        connect_rfcomm("00:16:53:0A:1B:2C", 0.5)
