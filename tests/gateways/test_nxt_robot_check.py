"""robocloud robot-check passes the NXT gateway with a stand-in brick: three real processes."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from loopback_ports import free_port
from robocloud.conformance import RULES

pytestmark = pytest.mark.slow

EXAMPLE = Path(__file__).parents[2] / "examples" / "nxt" / "thesis-bricks.json"
ROBOT = "nxt-tribot"  # it turns before it drives, and its grabber moves the arm
# The kit's windows for this robot (the gateway publishes twice a second and at once on
# every change): last_task watched for 1.5 s, 0.6 s after a command, an outage of 0.5 s;
# the deadlines keep their documented values.
OPTIONS = ["--linger", "1.5", "--watch", "0.6", "--outage", "0.5"]


def test_robot_check_passes_the_gateway_with_a_stand_in_brick(tmp_path: Path) -> None:
    data = json.loads(EXAMPLE.read_text())
    data["robots"] = {
        ROBOT: {**data["robots"][ROBOT], "reach": {"tcp": f"127.0.0.1:{free_port()}"}}
    }
    bricks = tmp_path / "bricks.json"
    bricks.write_text(json.dumps(data))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robocloud = [sys.executable, "-m", "robocloud.cli.main"]
    log = open(tmp_path / "parts.log", "ab")  # noqa: SIM115
    brick = subprocess.Popen(
        [*robocloud, "nxt-brick", "--bricks", str(bricks), "--robot", ROBOT, "--speedup", "3"],
        stdout=log, stderr=log,
    )  # fmt: skip
    gateway = subprocess.Popen(
        [*robocloud, "nxt", "--cloud", "cloud-a", "--connect", endpoint, "--bricks", str(bricks)],
        stdout=log, stderr=log,
    )  # fmt: skip
    try:
        check = subprocess.run(
            [*robocloud, "robot-check", "--connect", endpoint, "--cloud", "cloud-a",
             "--robot", ROBOT, *OPTIONS],
            capture_output=True, text=True, timeout=180,
        )  # fmt: skip
    finally:
        for process in (gateway, brick):
            process.terminate()
            process.wait(10)
        log.close()
    lines = check.stdout.splitlines()
    assert check.returncode == 0, check.stdout + check.stderr
    assert lines[-1] == f"{len(RULES)} passed, 0 failed"
