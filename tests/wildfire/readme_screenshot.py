"""Take the README's screenshot of the page in use: ``docs/wildfire.png``, 1280x800.

    .venv/bin/python tests/wildfire/readme_screenshot.py [OUTPUT.png]

Starts the real system (an IaaS, 60 simulated robots, the wildfire server) in
a temporary folder, sends a few requests through the page as an operator
would, and shoots while the last one is underway. Not a test: run it by hand
when the page's look changes.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from playwright.sync_api import expect, sync_playwright
from wildfire_system import CHROMIUM, CHROMIUM_ARGS, System

ROOT = Path(__file__).resolve().parents[2]
AREA = (84, 14, 958, 888, 990, 930)  # the map's plot area in its viewBox, as js/map.js


def click_forest(page: Any, x: float, y: float) -> None:
    left, top, right, bottom, width, height = AREA
    box = page.locator("#map").bounding_box()
    sx = left + x / 2000 * (right - left)
    sy = top + (2000 - y) / 2000 * (bottom - top)
    page.mouse.click(box["x"] + sx / width * box["width"], box["y"] + sy / height * box["height"])


def fill(
    page: Any,
    caps: dict[str, int],
    label: str,
    priority: str = "time",
    max_time: str = "1800",
    min_battery: str = "20",
) -> None:
    for row in page.locator("#caps .cap").all():
        row.locator("input").fill(str(caps.get(row.get_attribute("data-cap"), 0)))
    page.fill("#max-robots", "6")
    page.fill("#max-cost", "400")
    page.fill("#max-time", max_time)
    page.fill("#min-battery", min_battery)
    page.click(f"label[for=prio-{priority}]")
    page.fill("#label", label)


def main(output: Path) -> None:
    with tempfile.TemporaryDirectory() as folder:
        system = System(Path(folder), clouds=3, robots=30, speedup=15.0, seed=3)
        try:
            system.start()
            with sync_playwright() as playwright:
                browser = playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
                page = browser.new_page(viewport={"width": 1280, "height": 800})
                page.goto(system.url)
                expect(page.locator("#caps .cap").first).to_be_attached(timeout=15_000)
                # An earlier request, canceled on its way.
                click_forest(page, 1500, 450)
                fill(page, {"kicker": 1, "sound": 1}, "east track", "cost")
                page.click("#send")
                expect(page.locator("#state-head")).to_have_attribute(
                    "data-state", "underway", timeout=20_000
                )
                page.click("#cancel")
                expect(page.locator("#state-head")).to_have_attribute("data-state", "canceled")
                # One the fleet cannot meet: its reason is kept.
                click_forest(page, 300, 1800)
                fill(page, {"grabber": 5, "light": 3}, "north ridge", max_time="300")
                page.click("#send")
                expect(page.locator("#state-head")).to_have_attribute(
                    "data-state", "rejected", timeout=20_000
                )
                # The one in the picture: two grabbers and a touch sensor.
                click_forest(page, 1040, 1130)
                fill(page, {"grabber": 2, "touch": 1}, "valley fire", "balanced")
                page.click("#send")
                expect(page.locator("#state-head")).to_have_attribute(
                    "data-state", "underway", timeout=20_000
                )
                time.sleep(25)
                page.locator("#map").blur()
                page.screenshot(path=str(output))
                browser.close()
        finally:
            system.stop()
    print(f"wrote {output}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "wildfire.png")
