"""Free loopback ports for the processes a test starts, picked below the ephemeral range.

A port the kernel hands out for ``bind(("127.0.0.1", 0))`` comes from its
range of ephemeral ports (``/proc/sys/net/ipv4/ip_local_port_range``, 32768 to
60999 here), the range it also takes the source port of every outgoing
connection from. Picked so and bound by a process started seconds later, it
can be taken meanwhile (seen in CI: cloud-c's Zenoh port taken while cloud-a
and cloud-b connected to each other, "Address already in use"). A port below
that range is never given to an outgoing connection.
"""

from __future__ import annotations

import random
import socket
from pathlib import Path

LOWEST = 10_000
_pick = random.Random()  # seeded from the OS: each test process picks its own


def _ephemeral_start() -> int:
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 32_768


def free_port() -> int:
    """A loopback port free now, below the ephemeral range (any free one if there is no room)."""
    high = _ephemeral_start() - 1
    for _ in range(200 if high > LOWEST else 0):
        port = _pick.randint(LOWEST, high)
        with socket.socket() as sock:
            try:
                sock.bind(("127.0.0.1", port))
            except OSError:
                continue
        return port
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        found: int = sock.getsockname()[1]
    return found


def free_endpoint() -> str:
    """A Zenoh TCP endpoint on a loopback port free now (``free_port``)."""
    return f"tcp/127.0.0.1:{free_port()}"
