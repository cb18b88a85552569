"""A mission sent from the page to real IaaSs and simulated robots, followed to its end.

Two clouds in a federation (an IaaS and 25 simulated robots each, at 200 times
the clock: the mission's robot minutes are wall seconds) and ``robocloud
wildfire`` given both, every one a subprocess on loopback. Three fires, one
waiting for another, are placed, sent as one mission, and the MISSION tab's
Gantt chart shows the plan carried out until every fire is done and the
mission is completed.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from playwright.sync_api import expect
from wildfire_page import place_fire, wait_for_fleet, want
from wildfire_system import System

pytestmark = pytest.mark.slow

ROBOTS = 25


@pytest.fixture(scope="module")
def system(tmp_path_factory: pytest.TempPathFactory) -> Iterator[System]:
    # No selection workers (a mission's planner is a child of its own): two fewer
    # processes per IaaS to start.
    the_system = System(tmp_path_factory.mktemp("wildfire-mission"), clouds=2, robots=ROBOTS,
                        speedup=200.0, seed=11, iaas_args=["--selection-workers", "0"])
    try:
        yield the_system.start()
    finally:
        the_system.stop()


def near_idle(robots: list[dict[str, Any]], capability: str, count: int) -> list[tuple[int, int]]:
    """Places beside ``count`` different idle robots with ``capability``, inside the forest."""
    idle = [r for r in robots if r["status"] == "idle" and capability in r["capabilities"]
            and r["battery"] >= 40]
    assert len(idle) >= count, f"{len(idle)} idle robots with {capability}"
    places = []
    for r in idle[:count]:
        angle = len(places) * 2.1
        places.append((int(min(1950, max(50, r["x"] + 60 * math.cos(angle)))),
                       int(min(1950, max(50, r["y"] + 60 * math.sin(angle))))))
    return places


def test_a_mission_sent_from_the_page_is_carried_out_to_the_end(
        page: Any, system: System, screenshots: Path) -> None:
    wait_for_fleet(page, system.total)
    robots = httpx.get(f"{system.url}api/robots").json()
    # The capability most idle robots bring (the simulated clouds keep some busy with other work).
    offers = httpx.get(f"{system.url}api/capabilities").json()
    capability = max(offers, key=lambda o: o["idle"])["name"]
    fires = near_idle(robots, capability, 3)
    page.click("label[for='send-mission']")
    page.fill("#max-time", "")
    page.fill("#min-battery", "30")
    for x, y in fires:
        place_fire(page, x, y)
        want(page, {capability: 1})
        page.fill("#fire-duration", "30")
        page.click("#add-fire")
        expect(page.locator("#send-result")).to_contain_text("added at")
    page.select_option("#order-after", "fire-2")
    page.select_option("#order-before", "fire-1")
    page.click("#add-order")
    page.fill("#label", "three real fires")
    page.click("#send")
    expect(page.locator("#send-result")).to_have_text(re.compile(r"^Sent mis-"), timeout=30_000)
    view = page.locator("#mission-view")
    expect(view).to_be_visible()
    mission_id = view.get_attribute("data-mission")
    # The plan, drawn: a row a robot of the plan, a bar a fire each member works.
    expect(page.locator("#gantt-chart .gantt-row").first).to_be_attached(timeout=30_000)
    expect(page.locator("#gantt-chart .bar")).to_have_count(3)
    expect(page.locator("#map .route").first).to_be_attached()
    page.screenshot(path=str(screenshots / "mission-real-underway.png"))
    # Carried out to the end, followed live by the chart.
    expect(page.locator("#mission-state")).to_have_text("completed", timeout=120_000)
    expect(page.locator("#mission-progress")).to_have_text("100%")
    expect(page.locator("#mission-tasks li[data-state='done']")).to_have_count(3)
    expect(page.locator("#gantt-chart .bar[data-state='done']")).to_have_count(3)
    expect(page.locator("#mission-cancel")).to_be_disabled()
    # The send's line followed it: green once underway, and now completed.
    expect(page.locator("#send-result")).to_have_text(
        f"Sent {mission_id} (“three real fires”): completed.")
    page.screenshot(path=str(screenshots / "mission-real-completed.png"))
    # What the page shows is the IaaS's: the same plan, every fire done.
    with system.iaas() as iaas:
        mission = iaas.get(f"/v1/missions/{mission_id}").json()
    assert mission["state"] == "completed"
    assert [t["state"] for t in mission["plan"]["tasks"]] == ["done"] * 3
    tasks = {t["id"]: t for t in mission["plan"]["tasks"]}
    assert tasks["fire-2"]["start"] >= tasks["fire-1"]["end"] - 1e-6
    expect(page.locator("#mission-version")).to_have_text(f"v{mission['plan']['version']}")
