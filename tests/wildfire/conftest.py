"""Fixtures of the browser tests: the real system, Debian's chromium driven by Playwright.

Playwright launches the system's chromium (``tests/chromium_browser.py``):
without it the tests fail with what to install, never skip: CI must run them.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from playwright.sync_api import expect
from wildfire_browser import Console, open_page
from wildfire_system import CHROMIUM_ARGS, System

from chromium_browser import launch_chromium

# The machine is shared: a page's checks wait up to 10 s rather than Playwright's 5.
expect.set_options(timeout=10_000)


@pytest.fixture(scope="module")
def system(tmp_path_factory: pytest.TempPathFactory) -> Iterator[System]:
    # Three clouds in a federation, the page at the first: it sees every robot. The
    # server reads them and tells the page twice a second: a check sees a change sooner.
    the_system = System(tmp_path_factory.mktemp("wildfire-system"), clouds=3, robots=20,
                        wildfire_args=["--tick", "0.5"])
    try:
        yield the_system.start()
    finally:
        the_system.stop()


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    from playwright.sync_api import sync_playwright

    playwright = sync_playwright().start()
    try:
        the_browser = launch_chromium(playwright, CHROMIUM_ARGS)
        try:
            yield the_browser
        finally:
            the_browser.close()
    finally:
        playwright.stop()


@pytest.fixture(scope="session")
def screenshots(request: pytest.FixtureRequest) -> Path:
    folder = Path(request.config.rootpath) / "test-output" / "wildfire"
    folder.mkdir(parents=True, exist_ok=True)
    return folder


@pytest.fixture
def console() -> Console:
    return Console()


@pytest.fixture
def page(browser: Any, system: System, console: Console, screenshots: Path,
         request: pytest.FixtureRequest) -> Iterator[Any]:
    yield from open_page(browser, system, console, screenshots, request.node.name)


@pytest.fixture
def phone_page(browser: Any, system: System, console: Console, screenshots: Path,
               request: pytest.FixtureRequest) -> Iterator[Any]:
    yield from open_page(browser, system, console, screenshots, request.node.name, 390, 844)
