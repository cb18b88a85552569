"""A page of the wildfire server in chromium, watched: console errors and off-server requests."""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from wildfire_system import System


@dataclass
class Console:
    """What the page said on its console, and the errors that a test expects."""

    errors: list[str] = field(default_factory=list)
    expected: list[re.Pattern[str]] = field(default_factory=list)

    def expect(self, pattern: str) -> None:
        self.expected.append(re.compile(pattern))

    def unexpected(self) -> list[str]:
        return [e for e in self.errors if not any(p.search(e) for p in self.expected)]


def open_page(browser: Any, system: System, console: Console, screenshots: Path,
              name: str, width: int = 1280, height: int = 800) -> Iterator[Any]:
    context = browser.new_context(viewport={"width": width, "height": height})
    page = context.new_page()
    page.set_default_timeout(15_000)

    def on_console(message: Any) -> None:
        if message.type == "error":
            location = message.location or {}
            console.errors.append(f"{message.text} [{location.get('url', '')}]")

    page.on("console", on_console)
    page.on("pageerror", lambda error: console.errors.append(f"page error: {error}"))
    # Nothing but this machine's loopback: no CDN, no other network. Only what is off
    # the server is routed (a pattern the browser side matches), so the page's own
    # requests do not each wait for this process.
    outside: list[str] = []

    def guard(route: Any) -> None:
        outside.append(route.request.url)
        route.abort()

    page.route(re.compile(f"^(?!{re.escape(system.url)})"), guard)
    page.goto(system.url)
    try:
        yield page
    finally:
        page.screenshot(path=str(screenshots / f"{name}.png"))
        context.close()
    assert not outside, f"the page asked for something off this server: {outside}"
    assert not console.unexpected(), f"console errors: {console.unexpected()}"
