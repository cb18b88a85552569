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
  const point = new DOMPoint(84 + x / 2000 * 874, 14 + (2000 - y) / 2000 * 874);
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
    """``selector`` is shown whole within the window, with no scrolling."""
    locator = page.locator(selector)
    expect(locator).to_be_visible()
    box = locator.bounding_box()
    size = page.viewport_size
    assert box is not None and size is not None
    assert box["x"] >= -0.5 and box["y"] >= -0.5, f"{selector} starts off the window: {box}"
    assert box["x"] + box["width"] <= size["width"] + 0.5, f"{selector} passes the right edge: {box}"
    assert box["y"] + box["height"] <= size["height"] + 0.5, (
        f"{selector} is below the fold of {size['width']}x{size['height']}: {box}")


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
