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
    """Click the ground near (x, y); a robot under the pointer opens its card instead, so
    step aside until the click lands on the ground. Returns where the fire is."""
    for attempt in range(8):
        tx, ty = x + 35 * attempt, y - 25 * attempt
        page.mouse.click(*map_point(page, tx, ty))
        if page.locator("#robot-card").is_visible():
            page.click("#robot-card-close")
            continue
        expect(page.locator("#fire-marker")).to_be_visible()
        placed = (float(page.input_value("#loc-x")), float(page.input_value("#loc-y")))
        assert placed == (pytest.approx(tx, abs=15), pytest.approx(ty, abs=15))
        return placed
    raise AssertionError("every click near the fire landed on a robot")


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
