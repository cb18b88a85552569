"""ROS 2 robots join a cloud: IaaS, gateway, a Zenoh router per stand-in Nav2 robot: processes.

Four stand-in robots (``robocloud.gateways.ros2.standin``, encoded with
pycdr2), each its own Zenoh router, as a robot runs rmw_zenohd or the
bridge: rmw_zenoh/jazzy, bridge/humble in /bot2, rmw_zenoh/humble in /bot3
(its map turned a quarter), and a Lyrical robot the file calls Humble. The
gateway (``robocloud ros2``) reaches each on its own session. Each robot logs
what it was asked, which the tests read.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import zenoh
from processes import Cloud, follow, wait_until

from loopback_ports import free_port

pytestmark = pytest.mark.slow

CAPS = {"cam": {"kind": "sensing", "time": 0.5, "cost": 1.0}}
SPEED = 15.0
ROBOTS: dict[str, dict[str, Any]] = {
    "ros-jazzy": {"scheme": "rmw_zenoh", "distro": "jazzy", "namespace": "",
                  "offset": {"x": 0.0, "y": 0.0, "yaw": 0.0}, "start": (0.0, 0.0)},
    "ros-bridge": {"scheme": "bridge", "distro": "humble", "namespace": "/bot2",
                   "offset": {"x": 20.0, "y": 0.0, "yaw": 0.0}, "start": (0.0, 0.0)},
    "ros-ns": {"scheme": "rmw_zenoh", "distro": "humble", "namespace": "/bot3",
               "offset": {"x": 0.0, "y": 20.0, "yaw": math.pi / 2}, "start": (2.0, 0.0)},
    "ros-wrong": {"scheme": "rmw_zenoh", "distro": "humble", "runs": "lyrical",
                  "namespace": "", "offset": {"x": -20.0, "y": 0.0, "yaw": 0.0},
                  "start": (0.0, 0.0)},
}  # fmt: skip


@dataclass
class Site:
    cloud: Cloud
    workdir: Path
    ports: dict[str, int]
    gateway: subprocess.Popen[bytes] | None = None
    gateway_up: float = 0.0  # monotonic: when the gateway said it runs
    robots: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)

    def events(self, robot: str) -> list[dict[str, Any]]:
        path = self.workdir / f"{robot}.jsonl"
        if not path.exists():
            return []
        return [json.loads(line) for line in path.read_text().splitlines() if line]

    def control(self, robot: str, what: str) -> None:
        """A knob of the stand-in, on its own router (as an operator would reach it)."""
        config = zenoh.Config()
        config.insert_json5("mode", '"client"')
        config.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{self.ports[robot]}"]))
        config.insert_json5("scouting/multicast/enabled", "false")
        session = zenoh.open(config)
        name = ROBOTS[robot]["namespace"].strip("/") or "root"
        try:

            def ask() -> bool:
                payload = json.dumps({"do": what})
                replies = session.get(f"robocloud-standin/{name}/control", payload=payload,
                                      timeout=2.0)  # fmt: skip
                return any(r.ok is not None for r in replies)

            wait_until(ask, 10, f"{robot} to take {what}")
        finally:
            session.close()  # type: ignore[no-untyped-call]

    def gateway_log(self) -> str:
        return (self.workdir / "gateway.log").read_text()


def start_robot(site: Site, robot: str) -> None:
    spec = ROBOTS[robot]
    x, y = spec["start"]
    site.robots[robot] = subprocess.Popen(
        [sys.executable, "-m", "robocloud.gateways.ros2.standin",
         "--listen", f"tcp/127.0.0.1:{site.ports[robot]}", "--scheme", spec["scheme"],
         "--distro", spec.get("runs", spec["distro"]), "--namespace", spec["namespace"],
         "--x", str(x), "--y", str(y), "--speed", str(SPEED), "--battery", "0.8",
         "--feedback-hz", "20", "--tf-hz", "10", "--log", str(site.workdir / f"{robot}.jsonl")],
        stdout=subprocess.DEVNULL, stderr=open(site.workdir / f"{robot}.err", "ab"),  # noqa: SIM115
    )  # fmt: skip


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Site]:
    workdir = tmp_path_factory.mktemp("ros2")
    cloud = Cloud("cloud-a", workdir, f"sqlite:///{workdir / 'cloud-a.db'}", robots=0, speedup=1.0)
    site = Site(cloud, workdir, {robot: free_port() for robot in ROBOTS})
    robots_file = workdir / "robots.json"
    robots_file.write_text(json.dumps({"robots": {
        robot: {"endpoint": f"tcp/127.0.0.1:{site.ports[robot]}", "scheme": spec["scheme"],
                "domain": 0, "namespace": spec["namespace"], "distro": spec["distro"],
                "offset": spec["offset"], "speed": SPEED, "capabilities": CAPS}
        for robot, spec in ROBOTS.items()}}))  # fmt: skip
    try:
        for robot in ROBOTS:
            start_robot(site, robot)
        cloud.start_iaas()
        for robot in ROBOTS:
            wait_until(lambda r=robot: "stand-in:" in (workdir / f"{r}.err").read_text(), 60,
                       f"{robot} to run")  # fmt: skip
        site.gateway = subprocess.Popen(
            [sys.executable, "-m", "robocloud.cli.main", "ros2", "--cloud", "cloud-a",
             "--connect", cloud.zenoh, "--robots", str(robots_file)],
            stdout=subprocess.DEVNULL, stderr=open(workdir / "gateway.log", "ab"),  # noqa: SIM115
        )  # fmt: skip
        wait_until(lambda: "ROS 2 gateway:" in site.gateway_log(), 60, "the gateway to run")
        site.gateway_up = time.monotonic()
        yield site
    finally:
        for process in [*site.robots.values(), site.gateway]:
            if process is not None and process.poll() is None:
                process.terminate()
        for process in [*site.robots.values(), site.gateway]:
            if process is not None:
                process.wait(10)
        cloud.stop()


def robots(site: Site) -> dict[str, dict[str, Any]]:
    with site.cloud.client() as client:
        return {r["id"]: r for r in client.get("/v1/robots").json()}


def wait_idle(site: Site, names: list[str], timeout: float = 10.0) -> dict[str, dict[str, Any]]:
    def check() -> dict[str, dict[str, Any]] | None:
        seen = robots(site)
        ok = all(seen.get(n, {}).get("status") == "idle" for n in names)
        return seen if ok else None

    result: dict[str, dict[str, Any]] = wait_until(check, timeout, f"{names} idle")
    return result


def request(site: Site, location: list[float]) -> str:
    task = {"location": location, "sensing": {"cam": 1}, "max_robots": 1,
            "max_cost": 100_000.0, "max_time": 100_000.0, "priority": "time"}  # fmt: skip
    with site.cloud.client() as client:
        response = client.post("/v1/requests", json=task)
        assert response.status_code in (200, 201, 202), response.text
        rid: str = response.json()["id"]
    return rid


def details(body: dict[str, Any]) -> list[str]:
    return [h["detail"] or "" for h in body["history"]]


def goals_of(site: Site, robot: str) -> list[dict[str, Any]]:
    return [e for e in site.events(robot) if e["event"] == "send_goal"]


def test_the_robots_join_idle_at_their_place_and_battery_the_wrong_distro_offline(
    site: Site,
) -> None:
    # Within 5 s of the gateway's start (the module's first test).
    left = 5.0 - (time.monotonic() - site.gateway_up)
    seen = wait_idle(site, ["ros-jazzy", "ros-bridge", "ros-ns"], timeout=left)
    # The stand-in's base sits at its start in the map; odom is at (1, 0.5) between.
    assert seen["ros-jazzy"]["position"] == [pytest.approx(0.0), pytest.approx(0.0)]
    assert seen["ros-bridge"]["position"] == [pytest.approx(20.0), pytest.approx(0.0)]
    # A quarter turn: map (2, 0) is 2 m along the cloud's y from the offset (0, 20).
    assert seen["ros-ns"]["position"] == [pytest.approx(0.0, abs=1e-6), pytest.approx(22.0)]
    for robot in ("ros-jazzy", "ros-bridge", "ros-ns"):
        assert seen[robot]["battery"] == pytest.approx(80.0, abs=0.01)  # 0.8 made a percent
        assert seen[robot]["capabilities"] == ["cam"]
    wrong = wait_until(lambda: robots(site).get("ros-wrong"), 5, "the Lyrical robot to show")
    assert wrong["status"] == "offline"
    log = site.gateway_log()
    assert "robot ros-wrong is not selectable" in log
    assert "the robot runs a newer distro than humble" in log


def test_a_request_is_served_end_to_end_with_a_goal_in_the_robots_map(site: Site) -> None:
    wait_idle(site, ["ros-jazzy", "ros-bridge", "ros-ns"])
    rid = request(site, [0.0, 30.0])  # nearest: ros-ns at (0, 22)
    with site.cloud.client() as client:
        done = follow(client, rid, lambda r: r["state"] in ("completed", "failed"), 20, "the end")
    assert done["state"] == "completed", details(done)
    assert [a["robot"] for a in done["coalition"]] == ["ros-ns"]
    goal = goals_of(site, "ros-ns")[-1]
    # cloud (0, 30) = (0, 20) + R(90 degrees) * map, so map (10, 0), in frame map.
    assert (goal["x"], goal["y"]) == (pytest.approx(10.0), pytest.approx(0.0, abs=1e-6))
    assert goal["frame"] == "map" and goal["accepted"]
    assert robots(site)["ros-ns"]["position"] == [pytest.approx(0.0, abs=0.01), pytest.approx(30.0)]
    assert not [e for r in ROBOTS for e in site.events(r) if e["event"] == "bad_request"]


def test_a_cancel_reaches_the_robot_as_cancel_goal_for_that_goal(site: Site) -> None:
    wait_idle(site, ["ros-jazzy", "ros-bridge", "ros-ns"])
    rid = request(site, [-150.0, 0.0])  # far: ros-jazzy, nearest, drives for seconds
    with site.cloud.client() as client:
        underway = follow(client, rid, lambda r: r["state"] == "underway", 10, "underway")
        robot = underway["coalition"][0]["robot"]
        goal = wait_until(lambda: goals_of(site, robot), 5, "the goal")[-1]
        asked = time.time()
        assert client.post(f"/v1/requests/{rid}/cancel").json()["state"] == "canceled"
    cancel = wait_until(
        lambda: [e for e in site.events(robot) if e["event"] == "cancel_goal"], 5, "cancel_goal"
    )[-1]
    assert cancel["goal_id"] == goal["goal_id"]
    assert cancel["stamp"] == [0, 0]  # this goal alone, no older ones
    assert cancel["t"] - asked < 1.0  # the robot's clock is this machine's
    wait_idle(site, [robot], timeout=1.0)


@pytest.mark.parametrize(("knob", "reason"), [
    ("preempt", "navigation preempted by another goal"),
    ("nav2_down", "Nav2's action server navigate_to_pose vanished"),
])  # fmt: skip
def test_preemption_and_nav2_going_away_fail_the_robot_with_its_reason_and_re_plan(
    site: Site, knob: str, reason: str
) -> None:
    wait_idle(site, ["ros-jazzy", "ros-bridge", "ros-ns"])
    rid = request(site, [20.0, -15.0])  # ros-bridge first (at 20, 0), then another
    with site.cloud.client() as client:
        underway = follow(client, rid, lambda r: r["state"] == "underway", 10, "underway")
        first = underway["coalition"][0]["robot"]
        wait_until(lambda: goals_of(site, first), 5, "the goal")
        site.control(first, knob)
        done = follow(client, rid, lambda r: r["state"] in ("completed", "failed"), 30, "the end")
    history = details(done)
    # The robot's own sentence (task.reason), after the IaaS's words for how it failed.
    assert any(d.startswith(f"robot {first} failed: ") and reason in d for d in history), history
    assert done["state"] == "completed", history
    assert done["coalition"][0]["robot"] != first
    if knob == "nav2_down":
        assert robots(site)[first]["status"] == "offline"  # not chosen while Nav2 is gone
        site.control(first, "nav2_up")
        wait_idle(site, [first], timeout=5.0)
