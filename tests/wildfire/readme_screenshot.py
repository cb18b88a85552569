"""Take the README's screenshot of the page in use: ``docs/wildfire.png``, 1280x800.

    .venv/bin/python tests/wildfire/readme_screenshot.py [OUTPUT.png]

Starts the real system as ``make run`` has it (three clouds, 1,000 simulated
robots between them with their background activity, the clock 10 times
faster, the wildfire server given the three IaaSs) in a temporary folder,
sends a few requests through the page as an operator would, and shoots while
the last one is underway. Not a test: run it by hand when the page's look changes.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path
from typing import Any

from playwright.sync_api import expect, sync_playwright
from wildfire_page import fill_limits, type_fire, want
from wildfire_system import CHROMIUM, CHROMIUM_ARGS, System

ROOT = Path(__file__).resolve().parents[2]


def send(page: Any, x: float, y: float, caps: dict[str, int], label: str, priority: str,
         max_time: str = "1800", min_battery: str = "20", max_cost: str = "400") -> None:
    type_fire(page, x, y)
    want(page, caps)
    fill_limits(page, max_time=max_time, max_cost=max_cost, min_battery=min_battery,
                label=label, max_robots="6")
    page.click(f"label[for=prio-{priority}]")
    page.click("#send")
    expect(page.locator("#state-head")).to_contain_text(label, timeout=20_000)


def main(output: Path) -> None:
    with tempfile.TemporaryDirectory() as folder:
        system = System(Path(folder), clouds=3, robot_counts=[334, 333, 333], speedup=10.0,
                        seed=1, churn=True)
        try:
            system.start()
            with sync_playwright() as playwright:
                browser = playwright.chromium.launch(executable_path=CHROMIUM,
                                                     args=CHROMIUM_ARGS)
                page = browser.new_page(viewport={"width": 1280, "height": 800})
                page.goto(system.url)
                expect(page.locator("#map .robot")).to_have_count(1000, timeout=30_000)
                # An earlier request, canceled on its way.
                send(page, 1500, 450, {"kicker": 1, "sound": 1}, "east track", "cost")
                expect(page.locator("#state-head")).to_have_attribute(
                    "data-state", "underway", timeout=20_000)
                page.click("#cancel")
                page.click("#cancel-confirm")
                expect(page.locator("#state-head")).to_have_attribute("data-state", "canceled")
                # One the fleet cannot meet: its reason is kept.
                send(page, 300, 1800, {"grabber": 5, "light": 3}, "north ridge", "time",
                     max_time="60")
                expect(page.locator("#state-head")).to_have_attribute(
                    "data-state", "rejected", timeout=20_000)
                # The one in the picture: two grabbers and a touch sensor.
                send(page, 1040, 1130, {"grabber": 2, "touch": 1}, "valley fire", "balanced",
                     max_time="3600")
                expect(page.locator("#state-head")).to_have_attribute(
                    "data-state", "underway", timeout=20_000)
                page.wait_for_timeout(12_000)
                page.locator("#map").blur()
                page.screenshot(path=str(output))
                browser.close()
        finally:
            system.stop()
    print(f"wrote {output}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "wildfire.png")
