"""Helpers that drive the Wildfire page as an operator would, for the browser tests."""

from __future__ import annotations

import re
from typing import Any

import pytest
from playwright.sync_api import expect

FOREST = 2000.0
FINAL = re.compile(r"completed|rejected|canceled|failed")
# Where forest point (x, y) is in the map's viewBox at zoom 1 (js/map.js AREA).
TO_PAGE = """([x, y]) => {
  const svg = document.getElementById("map");
  const point = new DOMPoint(104 + x / 2000 * 874, 14 + (2000 - y) / 2000 * 874);
  const p = point.matrixTransform(svg.getScreenCTM());
  return [p.x, p.y];
}"""


def map_point(page: Any, x: float, y: float) -> tuple[float, float]:
    """Where forest point (x, y) is on the page (the whole forest in view)."""
    sx, sy = page.evaluate(TO_PAGE, [x, y])
    return float(sx), float(sy)


def place_fire(page: Any, x: float, y: float) -> tuple[float, float]:
    """Click the map at (x, y): in "Place fire" mode a click places the fire, on a robot
    too, and opens no robot's card. Returns where the fire is."""
    page.mouse.click(*map_point(page, x, y))
    expect(page.locator("#fire-marker")).to_be_visible()
    assert page.locator("#robot-card").is_hidden(), "a click meant for the fire opened a card"
    placed = (float(page.input_value("#loc-x")), float(page.input_value("#loc-y")))
    assert placed == (pytest.approx(x, abs=15), pytest.approx(y, abs=15))
    return placed


def in_view(page: Any, selector: str) -> None:
    """``selector`` is shown whole within the window, with no scrolling (an
    IntersectionObserver's ratio 1: neither the window nor a scrolled box cuts it)."""
    expect(page.locator(selector)).to_be_in_viewport(ratio=1)


def far_fire(robots: list[dict[str, Any]], capability: str) -> tuple[float, float]:
    """A point of the forest as far as can be from every idle robot with ``capability``:
    the robots sent there are long on their way, so a test can cancel them in time."""
    idle = [(r["x"], r["y"]) for r in robots
            if r["status"] == "idle" and capability in r["capabilities"]]
    grid = [(x * FOREST / 10, y * FOREST / 10) for x in range(11) for y in range(11)]
    return max(grid, key=lambda p: min(((p[0] - x) ** 2 + (p[1] - y) ** 2 for x, y in idle),
                                       default=0.0))


def type_fire(page: Any, x: float, y: float) -> None:
    page.fill("#loc-x", str(x))
    page.fill("#loc-y", str(y))


def wait_for_fleet(page: Any, robots: int | None = None) -> None:
    expect(page.locator("#connection")).to_have_attribute("data-state", re.compile("ok|partial"))
    expect(page.locator("#map .robot").first).to_be_attached()
    expect(page.locator("#caps .cap").first).to_be_attached()
    if robots is not None:
        expect(page.locator("#map .robot")).to_have_count(robots)


def fill_limits(page: Any, *, max_time: str = "900", max_cost: str = "100000",
                min_battery: str = "0", label: str = "", max_robots: str = "10") -> None:
    page.fill("#max-robots", max_robots)
    page.fill("#max-cost", max_cost)
    page.fill("#max-time", max_time)
    page.fill("#min-battery", min_battery)
    page.fill("#label", label)


def want(page: Any, caps: dict[str, int]) -> None:
    for row in page.locator("#caps .cap").all():
        row.locator("input").fill(str(caps.get(row.get_attribute("data-cap") or "", 0)))


def send(page: Any) -> str:
    page.click("#send")
    result = page.locator("#send-result")
    expect(result).to_have_text(re.compile(r"^Sent req-"), timeout=20_000)
    match = re.search(r"Sent (req-[\w-]+)", result.inner_text())
    assert match
    return match.group(1)


def wanted(page: Any) -> dict[str, int]:
    caps: dict[str, int] = {}
    for row in page.locator("#caps .cap").all():
        count = int(row.locator("input").input_value() or 0)
        if count:
            caps[row.get_attribute("data-cap") or ""] = count
    return caps


def api_post(page: Any, path: str, body: Any, headers: dict[str, str] | None = None
             ) -> dict[str, Any]:
    """A call from the page to the wildfire server, past the form's own checks."""
    answer: dict[str, Any] = page.evaluate(
        """async ([path, body, headers]) => {
            const r = await fetch(path, {
                method: "POST", body: JSON.stringify(body),
                headers: {"Content-Type": "application/json", ...headers}});
            return {status: r.status, body: await r.json()};
        }""", [path, body, headers or {}])
    return answer
