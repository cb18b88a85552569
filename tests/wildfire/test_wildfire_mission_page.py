"""The page's missions in chromium: built, sent, drawn as a Gantt chart, followed, canceled.

The wildfire server is the real one (a subprocess on loopback); the IaaS it
calls is a fake served over real HTTP (``served_iaas.py``) whose missions are
planned by ``fake_missions.plan`` from the robots' places and speeds, and
moved on by the test (``advance``, ``replan``), so every figure the page shows
can be checked against the plan the IaaS gave.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import pytest
from fake_iaas import KEY, FakeIaas, robot
from fake_missions import advance, replan
from playwright.sync_api import expect
from served_iaas import ServedIaas
from wildfire_browser import Console, open_page
from wildfire_page import map_point, place_fire, want
from wildfire_system import wait_until

from loopback_ports import free_port

pytestmark = pytest.mark.slow

ROBOTS = [
    robot("a-0001", "cloud-a", caps=("grabber", "light"), position=(200, 300)),
    robot("a-0002", "cloud-a", caps=("grabber",), position=(1700, 400)),
    robot("a-0003", "cloud-a", caps=("kicker", "light"), position=(900, 1800)),
    robot("b-0001", "cloud-b", caps=("kicker", "ultrasonic"), position=(1500, 1500)),
    robot("b-0002", "cloud-b", caps=("grabber", "ultrasonic"), position=(300, 1600)),
]


@dataclass
class FakeSystem:
    """A served fake IaaS and ``robocloud wildfire`` in front of it."""

    workdir: Path
    fake: FakeIaas = field(default_factory=lambda: FakeIaas("cloud-a", [dict(r) for r in ROBOTS]))
    port: int = field(default_factory=free_port)
    process: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}/"

    def start(self) -> FakeSystem:
        self.fake.listing = [{"cloud": c, "robots": n, "idle": n, "offline": 0}
                             for c, n in (("cloud-a", 3), ("cloud-b", 2))]
        self.served = ServedIaas(self.fake).start()
        self.log = open(self.workdir / "wildfire.log", "ab")  # noqa: SIM115 - closed in stop()
        self.process = subprocess.Popen(
            [sys.executable, "-m", "robocloud.wildfire.command", "--iaas", self.served.url,
             "--listen", f"127.0.0.1:{self.port}", "--log-level", "info"],
            stdout=self.log, stderr=subprocess.STDOUT,
            env={**os.environ, "ROBOCLOUD_WILDFIRE_API_KEY": KEY})
        wait_until(lambda: httpx.get(f"{self.url}api/health", timeout=2).status_code == 200, 30,
                   "the wildfire server to reach the fake IaaS")
        return self

    def stop(self) -> None:
        if self.process is not None:
            self.process.terminate()
            self.process.wait(10)
        self.served.stop()
        self.log.close()

    def missions_sent(self) -> list[httpx.Request]:
        return [c for c in self.fake.calls if c.method == "POST" and c.url.path == "/v1/missions"]

    def change(self, mission_id: str, how: Any) -> None:
        with self.fake.lock:
            how(self.fake.missions[mission_id])
        self.fake.changed()


@pytest.fixture(scope="module")
def system(tmp_path_factory: pytest.TempPathFactory) -> Iterator[FakeSystem]:
    the_system = FakeSystem(tmp_path_factory.mktemp("wildfire-missions"))
    try:
        yield the_system.start()
    finally:
        the_system.stop()


def add_fire(page: Any, x: float, y: float, caps: dict[str, int], work: str = "") -> None:
    place_fire(page, x, y)
    want(page, caps)
    page.fill("#fire-duration", work)
    page.click("#add-fire")
    expect(page.locator("#send-result")).to_contain_text("added at")


def start_mission_mode(page: Any) -> None:
    expect(page.locator("#map .robot")).to_have_count(len(ROBOTS))
    page.click("label[for='send-mission']")
    expect(page.locator("#mission-builder")).to_be_visible()
    expect(page.locator("#max-robots")).to_be_hidden()
    expect(page.locator("#send")).to_have_text("Send the Mission")
    # A mission's max time is its own (the last robot's return): empty at first.
    expect(page.locator("#max-time")).to_have_value("")
    expect(page.locator("#priority-help")).to_contain_text("last robot is home")
    page.fill("#min-battery", "0")


def gantt(page: Any) -> dict[str, Any]:
    """What the chart draws: each bar, wait and travel with its place, in plan seconds."""
    drawn: dict[str, Any] = page.evaluate("""async () => {
        const { ganttX } = await import("/static/js/gantt.js");
        const chart = document.getElementById("gantt-chart");
        const unit = ganttX(chart, 1) - ganttX(chart, 0);
        const at = (r) => (Number(r.getAttribute("x")) - ganttX(chart, 0)) / unit;
        const len = (r) => Number(r.getAttribute("width")) / unit;
        const rows = [...chart.querySelectorAll(".gantt-row")].map((row) => ({
            robot: row.dataset.robot, state: row.dataset.state,
            bars: [...row.querySelectorAll(".bar")].map((b) => ({
                task: b.dataset.task, state: b.dataset.state, start: at(b), length: len(b),
                fill: b.getAttribute("fill")})),
            waits: [...row.querySelectorAll(".wait")].map((w) => ({
                task: w.dataset.task, start: at(w), length: len(w)})),
            travel: row.querySelectorAll(".travel").length,
            done: [...row.querySelectorAll(".bar-done")].map((d) => ({
                task: d.dataset.task, length: len(d)})),
        }));
        const now = document.getElementById("gantt-now");
        return {version: chart.dataset.version, rows, now: now ? Number(now.dataset.at) : null};
    }""")
    return drawn


def test_several_fires_are_sent_as_one_mission_and_its_plan_is_drawn(
        page: Any, system: FakeSystem, screenshots: Path) -> None:
    start_mission_mode(page)
    add_fire(page, 400, 500, {"grabber": 1})
    add_fire(page, 1300, 700, {"kicker": 1, "light": 1}, work="30")
    add_fire(page, 800, 1400, {"grabber": 1, "ultrasonic": 1})
    expect(page.locator("#mission-fires li")).to_have_count(3)
    # Drafted on the map, numbered.
    expect(page.locator("#map .mission-fire.draft")).to_have_count(3)
    # fire-3 waits for fire-1.
    page.select_option("#order-after", "fire-3")
    page.select_option("#order-before", "fire-1")
    page.click("#add-order")
    expect(page.locator("#mission-orders li")).to_have_text(["fire-3 after fire-1 is out×"])
    # A circle is refused, with a sentence.
    page.select_option("#order-after", "fire-1")
    page.select_option("#order-before", "fire-3")
    page.click("#add-order")
    expect(page.locator("#err-mission")).to_have_text(
        "fire-1 after fire-3 would make a circle: some fire would wait for itself.")
    # The end place, clicked on the map in "End place" mode.
    page.click("label[for='mode-end']")
    page.mouse.click(*map_point(page, 100, 100))
    expect(page.locator("#end-on")).to_be_checked()
    expect(page.locator("#map #mission-end-draft")).to_be_visible()
    page.fill("#label", "three fires")
    page.screenshot(path=str(screenshots / "mission-built.png"))
    page.click("#send")
    result = page.locator("#send-result")
    expect(result).to_have_text(re.compile(
        r"^Sent mis-\w+ \(“three fires”\): underway, plan 1, [2-5] robots\.$"))
    expect(result).to_have_attribute("data-kind", "ok")

    # ONE mission reached the IaaS, as the page built it, with a key.
    [sent] = system.missions_sent()
    assert re.fullmatch(r"wf-[0-9a-f]{32}", sent.headers["idempotency-key"])
    body = json.loads(sent.content)
    assert [t["id"] for t in body["tasks"]] == ["fire-1", "fire-2", "fire-3"]
    assert body["tasks"][0]["actuating"] == {"grabber": 1} and body["tasks"][0]["sensing"] == {}
    assert body["tasks"][1] == {**body["tasks"][1], "actuating": {"kicker": 1},
                                "sensing": {"light": 1}, "duration": 30}
    assert body["tasks"][2]["location"] == [pytest.approx(800, abs=15),
                                            pytest.approx(1400, abs=15)]
    assert "duration" not in body["tasks"][0]
    assert body["precedence"] == [["fire-1", "fire-3"]]
    assert body["end"] == [pytest.approx(100, abs=15), pytest.approx(100, abs=15)]
    assert body["label"] == "three fires" and body["max_time"] is None
    assert body["priority"] in ("time", "balanced", "cost") and body["min_battery"] == 0
    expect(page.locator("#mission-view")).to_have_attribute("data-mission", re.compile("mis-"))
    mission = system.fake.missions[page.get_attribute("#mission-view", "data-mission") or ""]
    plan = mission["plan"]

    # The MISSION tab: the plan's figures, and the chart, a row a robot.
    expect(page.locator("#mission-view")).to_be_visible()
    expect(page.locator("#mission-state")).to_have_text("underway")
    expect(page.locator("#mission-version")).to_have_text("v1")
    expect(page.locator("#mission-gap")).to_have_text(f"{round(plan['gap'] * 100)}%")
    drawn = gantt(page)
    assert [r["robot"] for r in drawn["rows"]] == [r["id"] for r in plan["robots"]]
    colours = {}
    for row, route in zip(drawn["rows"], plan["robots"], strict=True):
        assert [b["task"] for b in row["bars"]] == [leg["task"] for leg in route["legs"]]
        for bar, leg in zip(row["bars"], route["legs"], strict=True):
            assert bar["start"] == pytest.approx(leg["start"], abs=plan["makespan"] / 300)
            assert bar["length"] == pytest.approx(leg["end"] - leg["start"],
                                                  abs=plan["makespan"] / 300)
            colours.setdefault(bar["task"], set()).add(bar["fill"])
        waits = [leg for leg in route["legs"] if leg["start"] - leg["arrive"] > 0.05]
        assert [w["task"] for w in row["waits"]] == [leg["task"] for leg in waits]
        for wait, leg in zip(row["waits"], waits, strict=True):
            assert wait["length"] == pytest.approx(leg["start"] - leg["arrive"],
                                                   abs=plan["makespan"] / 300)
    # A colour a fire, the same in every row and on the map.
    assert all(len(c) == 1 for c in colours.values()) and len(colours) == 3
    assert any(row["waits"] for row in drawn["rows"]), "the plan has a wait the chart must show"
    assert drawn["now"] is not None
    # Each robot's route on the map: from its place, through its fires, to the end.
    routes = page.locator("#map .route")
    expect(routes).to_have_count(len(plan["robots"]))
    for route in plan["robots"]:
        points = page.get_attribute(f"#map .route[data-robot='{route['id']}']", "points") or ""
        assert len(points.split()) == len(route["legs"]) + 2
    expect(page.locator("#map .mission-fire:not(.draft)")).to_have_count(3)
    expect(page.locator("#map .mission-fire.draft")).to_have_count(0)
    page.screenshot(path=str(screenshots / "mission-sent.png"))


def test_the_plan_follows_the_mission_live_until_it_completes(
        page: Any, system: FakeSystem, screenshots: Path) -> None:
    # The newest mission is shown on a page that opens (the one the test above sent).
    [mission_id] = list(system.fake.missions)
    page.click("#tab-mission")
    expect(page.locator("#mission-view")).to_have_attribute("data-mission", mission_id)
    plan = system.fake.missions[mission_id]["plan"]
    first = min(plan["tasks"], key=lambda t: t["start"])
    middle = (first["start"] + first["end"]) / 2
    system.change(mission_id, lambda m: advance(m, middle))
    task = page.locator(f"#mission-tasks li[data-task='{first['id']}']")
    expect(task).to_have_attribute("data-state", "work")
    expect(task.locator(".task-state")).to_have_text(re.compile(r"^work (4\d|5\d)%$"))
    drawn = gantt(page)
    done = [d for row in drawn["rows"] for d in row["done"] if d["task"] == first["id"]]
    assert done and all(d["length"] == pytest.approx((first["end"] - first["start"]) / 2,
                                                     rel=0.1) for d in done)
    # A robot fails: the IaaS re-plans the fires not started without it.
    gone = next(r["id"] for r in plan["robots"]
                if all(leg["start"] > middle for leg in r["legs"]))
    system.change(mission_id, lambda m: replan(m, ROBOTS, middle, gone))
    expect(page.locator("#mission-version")).to_have_text("v2")
    expect(page.locator("#mission-history li").last).to_contain_text(
        f"re-planned (version 2): robot {gone} failed")
    expect(page.locator(f"#gantt-chart .gantt-row[data-robot='{gone}']")).to_have_attribute(
        "data-state", "failed")
    page.screenshot(path=str(screenshots / "mission-replanned.png"))
    # A robot at work for the mission says so in its card: which fire, which mission.
    worker = first["robots"][0]
    at_work = next(r for r in system.fake.robots if r["id"] == worker)
    at_work["status"], at_work["request"] = "busy", f"{mission_id}.1"
    expect(page.locator(f"#map .robot[data-robot='{worker}']")).to_have_attribute(
        "data-status", "busy")
    page.keyboard.down("Shift")
    page.mouse.click(*map_point(page, *at_work["position"]))
    page.keyboard.up("Shift")
    card = page.locator("#robot-card")
    expect(card).to_contain_text(f"fire-1 of mission “three fires” ({mission_id})")
    expect(card).to_contain_text("one of this application's missions")
    page.click("#robot-card-close")
    at_work["status"], at_work["request"] = "idle", None
    system.change(mission_id, lambda m: advance(m, 1e6))
    expect(page.locator("#mission-state")).to_have_text("completed")
    expect(page.locator("#mission-progress")).to_have_text("100%")
    expect(page.locator("#mission-tasks li[data-state='done']")).to_have_count(3)
    expect(page.locator("#mission-cancel")).to_be_disabled()
    expect(page.locator("#gantt-now")).to_have_count(0)
    # This page sent nothing: its send line is not the mission's.
    expect(page.locator("#send-result")).to_have_text("")
    wait_until(lambda: system.served.streams == 0, 10, "the event stream to close")


def test_a_mission_is_canceled_from_the_page(page: Any, system: FakeSystem) -> None:
    before = set(system.fake.missions)
    start_mission_mode(page)
    add_fire(page, 1000, 1000, {"grabber": 1})
    page.click("#send")
    expect(page.locator("#send-result")).to_have_text(re.compile(r"^Sent mis-\w+: underway"))
    [mission_id] = [m for m in system.fake.missions if m not in before]
    expect(page.locator("#mission-view")).to_have_attribute("data-mission", mission_id)
    assert mission_id and system.fake.missions[mission_id]["state"] == "underway"
    page.click("#mission-cancel")
    expect(page.locator("#mission-cancel-text")).to_contain_text(
        "Cancelling stops every robot of the mission")
    page.click("#mission-cancel-confirm")
    expect(page.locator("#mission-state")).to_have_text("canceled")
    expect(page.locator("#send-result")).to_have_text(f"{mission_id} was canceled.")
    assert [c.method for c in system.fake.calls
            if c.url.path == f"/v1/missions/{mission_id}"][-1] == "DELETE"
    expect(page.locator("#mission-tasks li[data-state='canceled']")).to_have_count(1)
    expect(page.locator("#mission-cancel")).to_be_disabled()


def test_the_page_refuses_a_mission_it_can_tell_is_wrong(page: Any, system: FakeSystem) -> None:
    start_mission_mode(page)
    sent = len(system.missions_sent())
    page.click("#send")
    expect(page.locator("#send-result")).to_have_text(
        "Check the field marked in red: Add at least one fire: place it, choose its needs, "
        "then Add this fire.")
    page.fill("#loc-x", "2500")
    page.fill("#loc-y", "10")
    want(page, {"grabber": 1})
    page.click("#add-fire")
    expect(page.locator("#err-location")).to_have_text(re.compile(r"outside the forest"))
    expect(page.locator("#mission-fires li")).to_have_count(0)
    add_fire(page, 500, 500, {"grabber": 1})
    page.fill("#end-x", "-50")
    page.fill("#end-y", "10")
    page.click("#send")
    expect(page.locator("#err-mission")).to_have_text(
        "The end place at (-50, 10) is outside the forest, which spans x from 0 to 2,000 m and "
        "y from 0 to 2,000 m.")
    assert len(system.missions_sent()) == sent


def test_on_a_phone_the_mission_is_a_tab_of_its_own(
        browser: Any, system: FakeSystem, console: Console, screenshots: Path) -> None:
    for phone in open_page(browser, system, console, screenshots,  # type: ignore[arg-type]
                           "mission-phone", 390, 844):
        expect(phone.locator("#mission-pick option").first).to_have_attribute(
            "value", re.compile("mis-"))
        phone.get_by_role("button", name="Mission", exact=True).click()
        expect(phone.locator("#gantt-chart")).to_be_visible()
        expect(phone.locator("#map")).to_be_hidden()
        assert phone.evaluate("""() => { const g = document.getElementById("gantt");
            return g.scrollWidth <= g.clientWidth + 1; }"""), "the chart is wider than a phone"
        phone.get_by_role("button", name="Send", exact=True).click()
        phone.click("label[for='send-mission']")
        expect(phone.locator("#add-fire")).to_be_visible()


def test_a_mission_with_no_plan_is_red_with_the_iaas_reason(page: Any, system: FakeSystem
                                                            ) -> None:
    start_mission_mode(page)
    add_fire(page, 700, 700, {"grabber": 3, "kicker": 3})
    page.click("#send")
    result = page.locator("#send-result")
    expect(result).to_have_text(re.compile(
        r"^mis-\w+ was rejected: Fire-1 needs 3 robots bringing 'kicker', and 2 do\.$"))
    expect(result).to_have_attribute("data-kind", "error")
    expect(page.locator("#mission-state")).to_have_text("rejected")
    expect(page.locator("#mission-reason")).to_have_text(
        "Fire-1 needs 3 robots bringing 'kicker', and 2 do.")
    expect(page.locator("#mission-tasks li[data-task='fire-1']")).to_have_attribute(
        "data-state", "not planned")
    expect(page.locator("#gantt-empty")).to_have_text("No plan: see the reason.")
    expect(page.locator("#mission-cancel")).to_be_disabled()
