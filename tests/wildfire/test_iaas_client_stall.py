"""A read that timed out while the wildfire server itself stood still is tried once more.

A real HTTP server on loopback holds its first answer; the client's event loop
is blocked (as when the process is stopped) past the read's timeout. The
timeout is then noticed late, which tells the stall from a slow IaaS.
"""

from __future__ import annotations

import asyncio
import time

import pytest

from robocloud.wildfire.iaas_client import STALL_MARGIN, IaasClient, IaasError

TIMEOUT = 0.3


class HoldFirst:
    """Answers every HTTP request with ``{"id": "r-1"}`` but the first, which it never answers."""

    def __init__(self) -> None:
        self.requests: list[bytes] = []

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        while head := await reader.readuntil(b"\r\n\r\n"):
            self.requests.append(head.split(b"\r\n", 1)[0])
            length = [int(line.split(b":")[1]) for line in head.split(b"\r\n")
                      if line.lower().startswith(b"content-length:")]
            if length:
                await reader.readexactly(length[0])
            if len(self.requests) == 1:
                await asyncio.sleep(60)
            body = b'{"id": "r-1", "state": "received"}'
            writer.write(b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\n"
                         b"Content-Length: %d\r\n\r\n%s" % (len(body), body))
            await writer.drain()


async def call_through_a_stall(method: str, stall: float) -> tuple[object, list[bytes]]:
    holder = HoldFirst()
    server = await asyncio.start_server(holder.serve, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    client = IaasClient(f"http://127.0.0.1:{port}", None, timeout=TIMEOUT)
    try:
        if method == "GET":
            call = asyncio.ensure_future(client.get_request("r-1"))
        else:
            call = asyncio.ensure_future(client.cancel_request("r-1"))
        while not holder.requests:
            await asyncio.sleep(0.01)
        time.sleep(stall)  # the whole process stands still, its timers with it
        try:
            outcome: object = await call
        except IaasError as error:
            outcome = error
    finally:
        await client.aclose()
        server.close()
    return outcome, holder.requests


def test_a_read_timed_out_during_a_stall_is_tried_once_more() -> None:
    outcome, requests = asyncio.run(call_through_a_stall("GET", TIMEOUT + STALL_MARGIN + 0.3))
    assert outcome == {"id": "r-1", "state": "received"}
    assert requests == [b"GET /v1/requests/r-1 HTTP/1.1"] * 2


def test_a_read_timed_out_on_time_is_a_504_without_a_second_try() -> None:
    outcome, requests = asyncio.run(call_through_a_stall("GET", 0.0))
    assert isinstance(outcome, IaasError) and outcome.status == 504
    assert "did not answer in time" in outcome.detail
    assert len(requests) == 1


@pytest.mark.parametrize("stall", [0.0, TIMEOUT + STALL_MARGIN + 0.3])
def test_a_cancel_is_never_sent_twice(stall: float) -> None:
    outcome, requests = asyncio.run(call_through_a_stall("POST", stall))
    assert isinstance(outcome, IaasError) and outcome.status == 504
    assert requests == [b"POST /v1/requests/r-1/cancel HTTP/1.1"]
