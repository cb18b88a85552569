"""Event streams are let go when their clients go: the request feed keeps none of them.

Issue 25: of 500 event streams opened and closed on a live IaaS, 188 were
still registered in the request feed 30 s later (and their memory held). A
stream was unregistered by its async generator, which a client gone while
changes were on their way left suspended, never closed, until Python's cycle
collector came by (rarely, in the IaaS: ``tune_runtime``). Now the HTTP route
holds the registration for as long as the response lasts.

One IaaS served by uvicorn on loopback (in-memory store and robot link).
Clients open streams, stop reading while the request changes many times
(the server's writes back up), and close. Once uvicorn has finished every
response (its task set is empty: the observable), the feed must hold no
stream. The cycle collector is off meanwhile, as rare as in the IaaS.
"""

from __future__ import annotations

import asyncio
import dataclasses
import gc
import socket
import threading
import time
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
import uvicorn

from robocloud.domain import Robot
from robocloud.fleet import MemoryRobotLink
from robocloud.iaas.app import create_app
from robocloud.iaas.config import Settings
from robocloud.iaas.service import RequestService
from robocloud.storage import MemoryRequestStore

KEY = {"Authorization": "Bearer k"}
STREAMS = 40
CHANGES = 300  # each about 8 KB of JSON: more than loopback's buffers take unread
TASK: dict[str, Any] = {
    "location": [0.0, 0.0],
    "actuating": {"grabber": 1},
    "max_robots": 1,
    "max_cost": 1000.0,
    "max_time": 100000.0,
    "label": "x" * 100,
}


@dataclasses.dataclass
class Served:
    url: str
    server: uvicorn.Server
    service: RequestService
    loop: asyncio.AbstractEventLoop


@pytest.fixture
def served() -> Iterator[Served]:
    robot = Robot.model_validate(
        {
            "id": "a-0000",
            "cloud": "cloud-a",
            "position": [100.0, 0.0],
            "speed": 1.0,
            "battery": 90.0,
            "status": "idle",
            "travel_cost_per_m": 0.1,
            "capabilities": {"grabber": {"kind": "actuating", "time": 50.0, "cost": 1.0}},
        }
    )
    link = MemoryRobotLink("cloud-a", [robot], offline_after=3600.0)
    app = create_app(
        Settings(cloud="cloud-a", api_keys={"k": "app"}, selection_workers=0),
        store=MemoryRequestStore(),
        link=link,
    )
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    config = uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning",
                            http="httptools")
    server = uvicorn.Server(config)
    loops: list[asyncio.AbstractEventLoop] = []

    def run() -> None:
        loop = asyncio.new_event_loop()
        loops.append(loop)
        loop.run_until_complete(server.serve())

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started:
        assert time.monotonic() < deadline and thread.is_alive(), "the IaaS did not start"
        time.sleep(0.02)
    yield Served(f"http://127.0.0.1:{port}", server, app.state.service, loops[0])
    server.should_exit = True
    thread.join(10)


def on_loop(served: Served, function: Any, *args: Any) -> Any:
    """``function(*args)`` on the server's event loop, its result here."""
    async def call() -> Any:
        return function(*args)

    return asyncio.run_coroutine_threadsafe(call(), served.loop).result(10)


async def open_and_abandon(served: Served, request_id: str) -> None:
    """STREAMS clients read the first event, stop reading while the request changes, close."""
    limits = httpx.Limits(max_connections=STREAMS + 5)
    async with httpx.AsyncClient(
        base_url=served.url, headers=KEY, timeout=30, limits=limits
    ) as client:
        opened = []
        for _ in range(STREAMS):
            context = client.stream("GET", f"/v1/requests/{request_id}/events")
            response = await context.__aenter__()
            lines = response.aiter_lines()
            while not (await lines.__anext__()).startswith("data:"):
                pass
            opened.append((context, lines))
        assert on_loop(served, served.service.feed.following) == STREAMS
        # Changes the clients do not read: the server's writes back up.
        base = served.service.store.get(request_id, "app")
        assert base is not None
        for i in range(CHANGES):
            change = dataclasses.replace(base, label=f"{i:04d}" + "y" * 8000)
            await asyncio.to_thread(on_loop, served, served.service.feed.publish, change)
        for context, lines in opened:
            await lines.aclose()
            await context.__aexit__(None, None, None)


def test_closed_streams_leave_nothing_in_the_feed(served: Served) -> None:
    answer = httpx.post(f"{served.url}/v1/requests", json=TASK, headers=KEY)
    request_id = answer.json()["id"]
    deadline = time.monotonic() + 10
    while httpx.get(f"{served.url}/v1/requests/{request_id}", headers=KEY).json()["state"] in (
        "received", "selecting"
    ):
        assert time.monotonic() < deadline
        time.sleep(0.02)
    collecting = gc.isenabled()
    gc.disable()
    try:
        asyncio.run(open_and_abandon(served, request_id))
        # The observable: uvicorn has finished every response (each stream's
        # task is done, its clean-up run), not a time.
        deadline = time.monotonic() + 30
        while on_loop(served, lambda: len(served.server.server_state.tasks)) > 0:
            assert time.monotonic() < deadline, "uvicorn did not finish the closed streams"
            time.sleep(0.05)
        assert on_loop(served, served.service.feed.following) == 0
    finally:
        if collecting:
            gc.enable()
