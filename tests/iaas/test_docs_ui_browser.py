"""``/docs`` in Debian's chromium with every request off the IaaS refused: Swagger UI still renders.

A real uvicorn server on loopback (the app over the in-memory store and robot
link) and Playwright driving ``/usr/bin/chromium``
(``tests/chromium_browser.py``: without it the test fails saying what to install).
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
import uvicorn

from chromium_browser import launch_chromium
from robocloud.fleet import MemoryRobotLink
from robocloud.iaas.app import create_app
from robocloud.iaas.config import Settings
from robocloud.storage import MemoryRequestStore

CHROMIUM_ARGS = ["--headless=new", "--no-sandbox", "--disable-gpu", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update"]


@pytest.fixture(scope="module")
def server() -> Iterator[str]:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    app = create_app(
        Settings(cloud="cloud-a", selection_workers=0),
        store=MemoryRequestStore(),
        link=MemoryRobotLink("cloud-a", []),
    )
    the_server = uvicorn.Server(
        uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning")
    )
    thread = threading.Thread(target=the_server.run, daemon=True)
    thread.start()
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 20
    while not the_server.started:
        assert time.monotonic() < deadline and thread.is_alive(), "the server did not start"
        time.sleep(0.05)
    assert httpx.get(f"{url}/healthz").status_code == 200
    yield url
    the_server.should_exit = True
    thread.join(10)


def test_swagger_ui_renders_with_no_network_but_the_iaas(server: str) -> None:
    from playwright.sync_api import expect, sync_playwright

    outside: list[str] = []
    errors: list[str] = []

    def guard(route: Any) -> None:
        if route.request.url.startswith(server):
            route.continue_()
        else:
            outside.append(route.request.url)
            route.abort()

    with sync_playwright() as playwright:
        browser = launch_chromium(playwright, CHROMIUM_ARGS)
        try:
            page = browser.new_page()
            page.set_default_timeout(15_000)
            page.on("pageerror", lambda error: errors.append(str(error)))
            page.route("**/*", guard)
            page.goto(f"{server}/docs")
            # Swagger UI drew the API from /openapi.json: its title and an operation.
            expect(page.locator(".swagger-ui .info .title")).to_contain_text("robocloud IaaS")
            expect(page.locator(".opblock-summary-path", has_text="/v1/requests").first
                   ).to_be_visible()
            paths = httpx.get(f"{server}/openapi.json").json()["paths"]
            expect(page.locator(".opblock")).to_have_count(sum(map(len, paths.values())))
        finally:
            browser.close()
    assert outside == []
    assert errors == []
