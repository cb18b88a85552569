"""``robocloud robot-check`` passes against the ROS 2 gateway fronting a stand-in robot."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from loopback_ports import free_port

pytestmark = pytest.mark.slow

# The kit's windows for this robot (the gateway publishes once a second and at once
# on every change): tasks of 1 s of travel (2 m at 2 m/s), last_task watched for
# 1.5 s, an outage of 0.5 s; the deadlines keep their documented values.
OPTIONS = ["--travel", "1", "--linger", "1.5", "--outage", "0.5"]


def test_robot_check_passes_against_the_gateway_and_a_stand_in(tmp_path: Path) -> None:
    robot_port, kit = free_port(), f"tcp/127.0.0.1:{free_port()}"
    robots = tmp_path / "robots.json"
    robots.write_text(json.dumps({"robots": {"tb-1": {
        "endpoint": f"tcp/127.0.0.1:{robot_port}", "scheme": "rmw_zenoh", "distro": "jazzy",
        "namespace": "/tb1", "offset": {"x": 10.0, "y": 5.0, "yaw": 0.5}, "speed": 2.0,
        "capabilities": {"camera": {"kind": "sensing", "time": 1.0, "cost": 1.0}}}}}))  # fmt: skip
    robot = subprocess.Popen(
        [sys.executable, "-m", "robocloud.gateways.ros2.standin", "--listen",
         f"tcp/127.0.0.1:{robot_port}", "--namespace", "/tb1", "--speed", "2"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    # The kit is the router the gateway connects to, so it starts first; the gateway waits.
    check = subprocess.Popen(
        [sys.executable, "-m", "robocloud.cli.main", "robot-check", "--connect", kit,
         "--cloud", "cloud-a", "--robot", "tb-1", *OPTIONS],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    gateway = subprocess.Popen(
        [sys.executable, "-m", "robocloud.cli.main", "ros2", "--cloud", "cloud-a", "--connect",
         kit, "--robots", str(robots), "--robot-keys", "--connect-timeout", "30"],
        stdout=subprocess.DEVNULL, stderr=open(tmp_path / "gateway.log", "ab"),  # noqa: SIM115
    )  # fmt: skip
    try:
        out, _ = check.communicate(timeout=180)
    finally:
        for process in (gateway, robot, check):
            if process.poll() is None:
                process.terminate()
            process.wait(10)
    assert check.returncode == 0, out + (tmp_path / "gateway.log").read_text()
    assert out.splitlines()[-1] == "18 passed, 0 failed"
