"""What a page costs a field link: the bytes chromium received over 6 s with 1,000 robots.

Three clouds with 1,000 simulated robots between them, their background
activity on and the clock 10 times faster, as ``make run`` has them; one page
open at 1440x900. Chromium's own network log (the DevTools protocol) counts
every byte that came over the wire, compressed, after the first snapshot,
each at the time chromium received it (the protocol's own timestamps): the
window is 6 s of the browser's clock from the first delta after the snapshot
was drawn. The goal of issue 12: under 20 KB/s steady (polling the whole fleet
was 258 KB/s; the stream is about 2 KB/s, ten times under the goal, so 6 s
of it, a delta a second, decide as the 30 s this test once waited did).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from playwright.sync_api import expect
from wildfire_browser import Console
from wildfire_system import System

pytestmark = pytest.mark.slow

ROBOTS = [334, 333, 333]
WINDOW_S = 6.0
GOAL_BYTES_PER_S = 20_000


@pytest.fixture(scope="module")
def system(tmp_path_factory: pytest.TempPathFactory) -> Iterator[System]:
    the_system = System(tmp_path_factory.mktemp("wildfire-1000"), clouds=3,
                        robot_counts=ROBOTS, speedup=10.0, seed=1, churn=True)
    try:
        yield the_system.start()
    finally:
        the_system.stop()


def test_a_page_receives_under_20_kb_a_second_with_1000_robots(
        browser: Any, system: System, console: Console, screenshots: Path) -> None:
    context = browser.new_context(viewport={"width": 1440, "height": 900})
    page = context.new_page()
    page.on("console", lambda m: console.errors.append(m.text) if m.type == "error" else None)
    cdp = context.new_cdp_session(page)
    cdp.send("Network.enable")
    # (chromium's monotonic clock in seconds, compressed bytes, decoded bytes)
    received: list[tuple[float, int, int]] = []
    deltas: list[tuple[float, dict[str, Any]]] = []  # (chromium's clock, the delta)
    cdp.on("Network.dataReceived",
           lambda e: received.append((float(e["timestamp"]), int(e["encodedDataLength"]),
                                      int(e["dataLength"]))))
    cdp.on("Network.eventSourceMessageReceived",
           lambda e: deltas.append((float(e["timestamp"]), json.loads(e["data"])))
           if e["eventName"] == "delta" else None)
    try:
        page.goto(system.url)
        expect(page.locator("#map .robot")).to_have_count(sum(ROBOTS), timeout=30_000)
        # The steady stream starts with the first delta after the snapshot was drawn; the
        # protocol's events come in order, so the snapshot's bytes were all counted before it.
        drawn = len(deltas)
        start = pump_until(page, lambda: deltas[drawn][0] if len(deltas) > drawn else None,
                           "a delta after the snapshot")
        end = start + WINDOW_S
        pump_until(page, lambda: bool(received) and received[-1][0] >= end,
                   f"{WINDOW_S:.0f} s of the stream")
        window = [n for when, n, _ in received if start <= when < end]
        decoded = sum(d for when, _, d in received if start <= when < end)
        rate = sum(window) / WINDOW_S
        changes = [delta for when, delta in deltas if start <= when < end]
        robot_changes = sum(len(d.get("robots", {}).get("set", [])) for d in changes)
        page.screenshot(path=str(screenshots / "thousand-robots.png"))
        whole = httpx.get(f"{system.url}api/robots", headers={"Accept-Encoding": "identity"})
        report = (f"{sum(window):,} bytes in {WINDOW_S:.0f} s = {rate / 1000:.2f} KB/s "
                  f"({decoded:,} bytes decoded; {len(changes)} deltas, {robot_changes:,} robot "
                  f"changes); "
                  f"the whole fleet as JSON is {len(whole.content) / 1000:.0f} KB\n")
        (screenshots / "bandwidth.txt").write_text(report)
        print(report)
        assert len(changes) >= WINDOW_S * 0.8, "a delta every tick"
        assert robot_changes > 100, "the fleet was changing: the measure means something"
        assert 0 < sum(window) < decoded, "compressed on the wire"
        assert rate < GOAL_BYTES_PER_S, report
    finally:
        context.close()
    assert not console.unexpected(), console.unexpected()


def pump_until(page: Any, value: Callable[[], Any], what: str, timeout: float = 30.0) -> Any:
    """Let Playwright deliver the DevTools events until ``value()`` is truthy; return it."""
    deadline = time.monotonic() + timeout
    while not (found := value()):
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")
        page.wait_for_timeout(100)
    return found
