"""``make run`` (``robocloud.cli.demo``) survives one cloud's failure and brings it back.

The demo small and fast (3 clouds, 60 robots, robots 250 times the clock) and
without a terminal, as CI runs it: its IaaS of cloud-b is killed, the demo
says so and goes on, the other clouds drop cloud-b and serve a request with
their own robots, ``kill -USR1`` restarts cloud-b, Ctrl-C stops it all.
"""

from __future__ import annotations

import os
import random
import re
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
from processes import follow, wait_until

KEY = "demo-test-key"
HEADERS = {"Authorization": f"Bearer {KEY}"}
CLOUDS = ["cloud-a", "cloud-b", "cloud-c"]


def free_block(count: int) -> int:
    """The first of ``count`` consecutive free loopback ports (the demo counts ports up)."""
    for _ in range(200):
        first = random.randrange(20_000, 60_000)
        socks = []
        try:
            for port in range(first, first + count):
                sock = socket.socket()
                socks.append(sock)
                sock.bind(("127.0.0.1", port))
            return first
        except OSError:
            continue
        finally:
            for sock in socks:
                sock.close()
    raise AssertionError(f"no {count} consecutive free ports")


@dataclass
class Demo:
    process: subprocess.Popen[bytes]
    out: Path
    err: Path
    http_port: int

    def url(self, cloud: str) -> str:
        return f"http://127.0.0.1:{self.http_port + CLOUDS.index(cloud)}"

    def client(self, cloud: str) -> httpx.Client:
        return httpx.Client(base_url=self.url(cloud), headers=HEADERS, timeout=10.0)

    def stdout(self) -> str:
        return self.out.read_text()

    def stderr(self) -> str:
        return self.err.read_text()

    def clouds_seen_by(self, cloud: str) -> list[str]:
        with self.client(cloud) as client:
            return [c["cloud"] for c in client.get("/v1/clouds").json()]


@pytest.fixture
def demo(tmp_path: Path) -> Iterator[Demo]:
    http, zenoh, wildfire = free_block(3), free_block(3), free_block(1)
    out, err = tmp_path / "demo.out", tmp_path / "demo.err"
    with open(out, "wb") as stdout, open(err, "wb") as stderr:
        process = subprocess.Popen(
            [
                sys.executable, "-m", "robocloud.cli.demo",
                "--clouds", "3", "--robots", "60", "--speedup", "250",
                "--var", str(tmp_path / "var"),
                "--http-port", str(http), "--zenoh-port", str(zenoh),
                "--wildfire-port", str(wildfire),
            ],
            stdin=subprocess.DEVNULL,  # no terminal, as in CI
            stdout=stdout,
            stderr=stderr,
            env={**os.environ, "ROBOCLOUD_DEMO_KEY": KEY},
        )
    the_demo = Demo(process, out, err, http)
    try:
        wait_until(
            lambda: "Ctrl-C stops everything." in the_demo.stdout() or process.poll() is not None,
            90,
            "the demo's banner",
        )
        assert process.poll() is None, the_demo.stderr()
        yield the_demo
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
            try:
                process.wait(30)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def serve_one_request(client: httpx.Client) -> dict[str, Any]:
    """A request for what an idle robot of the federation brings, until one completes.

    The demo's robots also start and end other work on their own (churn), so
    the robot in view may be taken before the request reaches it: try again.
    """
    body: dict[str, Any] = {}
    for _ in range(5):
        robots = client.get("/v1/robots", params={"scope": "federation"}).json()
        idle = [r for r in robots if r["status"] == "idle" and r["battery"] >= 30.0]
        assert idle, robots
        name, kind = next(iter(idle[0]["capability_kinds"].items()))
        task = {
            "location": [1000.0, 1000.0], kind: {name: 1}, "max_robots": 3,
            "max_cost": 100_000.0, "max_time": 100_000.0, "min_battery": 30.0,
        }
        created = client.post("/v1/requests", json=task)
        assert created.status_code == 202, created.text
        body = follow(client, created.json()["id"],
                      lambda r: r["state"] in ("completed", "failed", "rejected"), 60, "its end")
        if body["state"] == "completed":
            break
    return body


def test_the_demo_survives_a_cloud_s_failure_and_restarts_it(demo: Demo) -> None:
    banner = demo.stdout()
    assert "scope=federation" in banner
    assert "make reset" in banner or "rm -rf" in banner
    assert f"kill -USR1 {demo.process.pid}" in banner
    pids = {m[0]: int(m[1]) for m in re.findall(r"(cloud-\w): .*IaaS pid (\d+)", banner)}
    assert sorted(pids) == CLOUDS
    wait_until(lambda: demo.clouds_seen_by("cloud-a") == CLOUDS, 30, "three clouds")

    os.kill(pids["cloud-b"], signal.SIGKILL)
    wait_until(lambda: "cloud-b's IaaS stopped (exit -9)" in demo.stderr(), 10, "the report")
    report = demo.stderr()
    assert f"kill -USR1 {demo.process.pid}" in report
    assert "robocloud iaas --cloud cloud-b" in report  # the command to start it by hand
    assert demo.process.poll() is None  # the demo goes on

    # The others drop cloud-b and serve a request with their own robots.
    for cloud in ("cloud-a", "cloud-c"):
        wait_until(lambda c=cloud: demo.clouds_seen_by(c) == ["cloud-a", "cloud-c"], 15, "no b")
    with demo.client("cloud-c") as client:
        done = serve_one_request(client)
    assert done["state"] == "completed", done
    assert {m["cloud"] for m in done["coalition"]} <= {"cloud-a", "cloud-c"}

    # kill -USR1: what stopped starts again, and the federation has three clouds again.
    demo.process.send_signal(signal.SIGUSR1)
    wait_until(lambda: "cloud-b's IaaS is back." in demo.stderr(), 40, "cloud-b back")
    wait_until(lambda: demo.clouds_seen_by("cloud-a") == CLOUDS, 20, "cloud-b in /v1/clouds")
    restarted = int(re.findall(r"restarting cloud-b's IaaS \(pid (\d+)\)", demo.stderr())[0])

    # Ctrl-C: everything stops, nothing is left behind.
    demo.process.send_signal(signal.SIGINT)
    assert demo.process.wait(30) == 0
    for pid in (pids["cloud-a"], pids["cloud-c"], restarted):
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
    with pytest.raises(httpx.TransportError):
        httpx.get(f"{demo.url('cloud-a')}/healthz", timeout=2)
