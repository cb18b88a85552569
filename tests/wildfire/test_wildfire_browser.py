"""The Wildfire Suppression page in Debian's chromium, against a real IaaS and simulated robots.

Three clouds in a federation (an IaaS and 20 simulated robots each, at 100
times the clock) and ``robocloud wildfire`` at the first, all subprocesses on
loopback (``conftest.py``). Each test saves a
screenshot under ``test-output/wildfire/`` and fails on any console error it
did not expect, or on any request for something off the wildfire server.
"""

from __future__ import annotations

import re
from typing import Any

import pytest
from playwright.sync_api import expect
from wildfire_browser import Console
from wildfire_system import System

pytestmark = pytest.mark.slow

# The map's plot area in its viewBox (0 0 990 930), as js/map.js draws it.
AREA = {"left": 84, "top": 14, "right": 958, "bottom": 888, "width": 990, "height": 930}
FOREST = 2000.0
FINAL = re.compile(r"completed|rejected|canceled|failed")


def map_point(page: Any, x: float, y: float) -> tuple[float, float]:
    """Where forest point (x, y) is on the page."""
    box = page.locator("#map").bounding_box()
    sx = AREA["left"] + x / FOREST * (AREA["right"] - AREA["left"])
    sy = AREA["top"] + (FOREST - y) / FOREST * (AREA["bottom"] - AREA["top"])
    return (
        box["x"] + sx / AREA["width"] * box["width"],
        box["y"] + sy / AREA["height"] * box["height"],
    )


def place_fire(page: Any, x: float, y: float) -> None:
    page.mouse.click(*map_point(page, x, y))
    expect(page.locator("#fire-marker")).to_be_visible()
    assert float(page.input_value("#loc-x")) == pytest.approx(x, abs=15)
    assert float(page.input_value("#loc-y")) == pytest.approx(y, abs=15)


def wait_for_fleet(page: Any) -> None:
    expect(page.locator("#connection")).to_have_attribute("data-state", "ok")
    expect(page.locator("#map .robot").first).to_be_attached()
    expect(page.locator("#caps .cap").first).to_be_attached()


def fill_limits(
    page: Any,
    *,
    max_time: str = "900",
    max_cost: str = "100000",
    min_battery: str = "0",
    label: str = "",
) -> None:
    page.fill("#max-robots", "10")
    page.fill("#max-cost", max_cost)
    page.fill("#max-time", max_time)
    page.fill("#min-battery", min_battery)
    page.fill("#label", label)


def send(page: Any) -> str:
    page.click("#send")
    result = page.locator("#send-result")
    expect(result).to_have_text(re.compile(r"^Sent req-"))
    match = re.search(r"Sent (\S+):", result.inner_text())
    assert match
    return match.group(1)


def wanted(page: Any) -> dict[str, int]:
    caps: dict[str, int] = {}
    for row in page.locator("#caps .cap").all():
        count = int(row.locator("input").input_value() or 0)
        if count:
            caps[row.get_attribute("data-cap")] = count
    return caps


def test_the_page_loads_everything_from_the_server(page: Any, system: System) -> None:
    wait_for_fleet(page)
    expect(page.locator("#map .robot")).to_have_count(system.robots * system.clouds)
    expect(page.locator("#cloud-legend li")).to_have_count(system.clouds)
    for cloud in system.members:
        expect(page.locator(f"#cloud-legend li[data-cloud='{cloud.name}']")).to_contain_text(
            f"{cloud.name}{system.robots}"
        )
    fills = page.eval_on_selector_all(
        "#map .robot .shape", "shapes => shapes.map(s => s.getAttribute('fill'))"
    )
    assert len(set(fills)) == system.clouds, "each cloud has its colour"
    expect(page.locator("#iaas-name")).to_have_text("IaaS cloud-a")
    # Robots are coloured by cloud and shaped by state.
    statuses = set(page.eval_on_selector_all("#map .robot", "rs => rs.map(r => r.dataset.status)"))
    assert statuses <= {"idle", "reserved", "busy", "charging", "offline"}
    assert "idle" in statuses
    # Capabilities are offered from what the fleet has, each kind in its group.
    assert page.locator("#caps-actuating .cap[data-cap='grabber']").count() == 1
    assert page.locator("#caps-sensing .cap[data-cap='touch']").count() == 1
    for heading in ("Send a Request", "Get State of a Request", "Cancel a Request"):
        expect(page.get_by_role("button", name=heading)).to_be_visible()


def test_a_request_is_dispatched_underway_and_completed(page: Any, system: System) -> None:
    wait_for_fleet(page)
    place_fire(page, 1000, 1000)
    fill_limits(page, label="ridge fire")
    assert wanted(page), "the form starts from capabilities the fleet has"
    request_id = send(page)

    state = page.locator("#state-head")
    expect(state).to_have_attribute("data-request", request_id)
    expect(state).to_have_attribute("data-state", re.compile("underway|completed"), timeout=20_000)
    # The coalition is highlighted on the map, with a line to the fire, and the
    # Pareto front is plotted with the chosen coalition marked.
    coalition = page.locator("#coalition tbody tr")
    expect(coalition.first).to_be_attached()
    size = coalition.count()
    expect(page.locator("#map .robot.in-coalition")).to_have_count(size)
    assert page.locator("#map line.link").count() >= 1
    assert page.locator("#front svg circle.point").count() >= 1
    expect(page.locator("#front svg circle.point.chosen")).to_have_count(1)
    assert int(page.locator("#front circle.chosen").get_attribute("data-size")) == size
    expect(page.locator("#front .chosen-label")).to_have_text("chosen")

    expect(state).to_have_attribute("data-state", "completed", timeout=30_000)
    for step in ("received", "selecting", "dispatched", "underway", "completed"):
        expect(page.locator(f"#history li[data-state='{step}']").first).to_be_attached()
    expect(page.locator(f"#request-list li[data-request='{request_id}']")).to_have_attribute(
        "data-state", "completed"
    )
    expect(page.locator(f"#request-list li[data-request='{request_id}']")).to_contain_text(
        "ridge fire"
    )
    expect(page.locator("#coalition .progress[data-phase='done']")).to_have_count(size)
    expect(page.get_by_role("button", name="Cancel a Request")).to_be_disabled()
    # Every robot of the coalition is back to idle and shown so.
    robots = page.eval_on_selector_all("#coalition tbody tr", "rs => rs.map(r => r.dataset.robot)")
    for robot in robots:
        expect(page.locator(f"#map .robot[data-robot='{robot}']")).to_have_attribute(
            "data-status", "idle", timeout=10_000
        )


def test_another_request_is_canceled(page: Any, system: System) -> None:
    wait_for_fleet(page)
    # Typed, not clicked: a far corner, so the robots are still on their way.
    page.fill("#loc-x", "1990")
    page.fill("#loc-y", "10")
    expect(page.locator("#fire-marker")).to_have_attribute("data-x", "1990")
    fill_limits(page, max_time="100000")
    page.click("label[for=prio-cost]")
    expect(page.locator("#prio-cost")).to_be_checked()
    request_id = send(page)
    state = page.locator("#state-head")
    expect(state).to_have_attribute("data-request", request_id)
    expect(state).to_have_attribute("data-state", re.compile("dispatched|underway"), timeout=15_000)

    page.get_by_role("button", name="Cancel a Request").click()
    expect(page.locator("#cancel-result")).to_have_text(f"{request_id} is canceled.")
    expect(state).to_have_attribute("data-state", "canceled")
    expect(page.locator("#history li[data-state='canceled']")).to_have_count(1)
    expect(page.locator(f"#request-list li[data-request='{request_id}']")).to_have_attribute(
        "data-state", "canceled"
    )
    expect(page.get_by_role("button", name="Cancel a Request")).to_be_disabled()
    with system.iaas() as client:
        assert client.get(f"/v1/requests/{request_id}").json()["state"] == "canceled"


def test_a_bad_form_shows_each_error_beside_its_field(page: Any, system: System) -> None:
    wait_for_fleet(page)
    with system.iaas() as client:
        before = len(client.get("/v1/requests", params={"limit": 200}).json()["items"])
    fill_limits(page, max_cost="-5", min_battery="120")
    for row in page.locator("#caps .cap input").all():
        row.fill("0")
    page.click("#send")

    errors = {
        "#err-location": "Place the fire: click the map, or type x and y.",
        "#err-capabilities": "Ask for at least one capability: a count of 1 or more.",
        "#err-max_cost": "Max cost must be a positive number.",
        "#err-min_battery": "Min battery must be a percentage from 0 to 100.",
    }
    for slot, text in errors.items():
        expect(page.locator(slot)).to_have_text(text)
    expect(page.locator("#max-cost")).to_have_attribute("aria-invalid", "true")
    expect(page.locator("#loc-x")).to_have_attribute("aria-invalid", "true")
    expect(page.locator("#loc-x")).to_be_focused()
    assert "err-max_cost" in (page.get_attribute("#max-cost", "aria-describedby") or "")
    expect(page.locator("#send-result")).to_have_text("Check the fields marked in red.")
    expect(page.locator("#err-max_robots")).to_be_empty()

    # Fixing a field clears its error; nothing was sent.
    page.fill("#max-cost", "500")
    expect(page.locator("#err-max_cost")).to_be_empty()
    expect(page.locator("#max-cost")).not_to_have_attribute("aria-invalid", "true")
    with system.iaas() as client:
        assert len(client.get("/v1/requests", params={"limit": 200}).json()["items"]) == before


def test_the_iaas_sentence_is_shown_beside_the_field_it_names(page: Any, console: Console) -> None:
    wait_for_fleet(page)
    place_fire(page, 600, 1400)
    fill_limits(page)
    console.expect(r"status of 422 .*/api/requests")

    def refuse(route: Any) -> None:
        if route.request.method != "POST":
            route.fallback()
            return
        route.fulfill(
            status=422,
            content_type="application/json",
            body='{"detail": "max_time: input should be less than or equal to 1e9."}',
        )

    page.route("**/api/requests", refuse)
    page.click("#send")
    expect(page.locator("#err-max_time")).to_have_text(
        "Max_time: input should be less than or equal to 1e9."
    )
    expect(page.locator("#max-time")).to_have_attribute("aria-invalid", "true")
    expect(page.locator("#send-result")).to_contain_text("did not accept")


def test_get_state_of_a_request_by_its_id(page: Any, system: System, console: Console) -> None:
    wait_for_fleet(page)
    console.expect(r"status of 404 .*/api/requests/req-nothing")
    page.fill("#lookup-id", "req-nothing")
    page.get_by_role("button", name="Get State of a Request").click()
    expect(page.locator("#err-lookup")).to_contain_text("req-nothing")
    expect(page.locator("#lookup-id")).to_have_attribute("aria-invalid", "true")

    with system.iaas() as client:
        newest = client.get("/v1/requests", params={"limit": 1}).json()["items"][0]
    page.fill("#lookup-id", newest["id"])
    page.press("#lookup-id", "Enter")
    expect(page.locator("#state-head")).to_have_attribute("data-request", newest["id"])
    expect(page.locator("#err-lookup")).to_be_empty()
    item = page.locator(f"#request-list li[data-request='{newest['id']}'] button")
    expect(item).to_have_attribute("aria-current", "true")


def test_the_keyboard_alone_places_the_fire_and_sends(page: Any, system: System) -> None:
    wait_for_fleet(page)
    fill_limits(page, max_time="100000")
    page.focus("#send")
    page.keyboard.press("Tab")
    expect(page.locator("#map")).to_be_focused()
    page.keyboard.press("ArrowRight")  # the first key places the fire in the middle
    page.keyboard.press("ArrowRight")
    page.keyboard.press("Shift+ArrowUp")
    expect(page.locator("#loc-x")).to_have_value("1025")
    expect(page.locator("#loc-y")).to_have_value("1100")
    expect(page.locator("#map-status")).to_have_text("Fire placed at x 1025, y 1100.")
    page.keyboard.press("Shift+Tab")
    expect(page.locator("#send")).to_be_focused()
    page.keyboard.press("Enter")
    expect(page.locator("#send-result")).to_have_text(re.compile(r"^Sent req-"))
    request_id = page.locator("#send-result").inner_text().split()[1].rstrip(":")
    state = page.locator("#state-head")
    expect(state).to_have_attribute("data-request", request_id)
    expect(state).to_have_attribute("data-state", re.compile("dispatched|underway"), timeout=15_000)
    # Cancel it from the keyboard too: it is two steps back from Get State.
    page.focus("#get-state")
    page.keyboard.press("Shift+Tab")
    page.keyboard.press("Shift+Tab")
    expect(page.locator("#cancel")).to_be_focused()
    page.keyboard.press("Enter")
    expect(page.locator("#cancel-result")).to_have_text(f"{request_id} is canceled.")


def test_the_page_stacks_at_a_phones_width(phone_page: Any, system: System) -> None:
    page = phone_page
    wait_for_fleet(page)
    width = page.evaluate("document.documentElement.scrollWidth")
    assert width <= 390, f"the page is {width} px wide at a phone's 390"
    map_box = page.locator("#map").bounding_box()
    form_box = page.locator("#request-form").bounding_box()
    assert map_box["width"] >= 340
    assert map_box["y"] + map_box["height"] <= form_box["y"], "the map comes before the form"
    place_fire(page, 1400, 700)
    for target in ("#send", "#get-state", "#cancel"):
        box = page.locator(target).bounding_box()
        assert box["height"] >= 40, f"{target} is too small to tap"


def test_robots_of_several_clouds_are_coloured_by_cloud(page: Any) -> None:
    # The federation will make one IaaS list the robots of every cloud.
    robots = [
        {
            "id": f"{c[-1]}-{i:04d}",
            "cloud": c,
            "position": [100.0 + 300 * i, 200.0 * n],
            "speed": 1.0,
            "battery": 80.0,
            "status": status,
            "capabilities": ["light"],
            "request": None,
            "progress": None,
            "seen_ago": 0.1,
        }
        for n, c in enumerate(["cloud-a", "cloud-b", "cloud-c"], start=1)
        for i, status in enumerate(["idle", "busy", "offline"])
    ]
    page.route("**/api/robots", lambda route: route.fulfill(json=robots))
    expect(page.locator("#cloud-legend li")).to_have_count(3)
    expect(page.locator("#map .robot")).to_have_count(len(robots))
    fills = {}
    for cloud in ("cloud-a", "cloud-b", "cloud-c"):
        shapes = page.locator(f"#map .robot[data-cloud='{cloud}'] .shape")
        expect(shapes).to_have_count(3)
        fills[cloud] = {shape.get_attribute("fill") for shape in shapes.all()}
        assert len(fills[cloud]) == 1
    assert len(set.union(*fills.values())) == 3
    expect(page.locator("#forest-summary")).to_contain_text("9 robots of 3 clouds")
