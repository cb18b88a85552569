"""``python -m robocloud.sim.command`` as a process, connected to the test's router."""

import argparse
import signal
import socket
import subprocess
import sys
import time

import httpx
import pytest
from prometheus_client.parser import text_string_to_metric_families

from loopback_ports import free_endpoint
from robocloud.errors import InvalidInput
from robocloud.fleet import Assign, ZenohRobotLink, open_router
from robocloud.sim.command import add_sim_arguments, main, sim_command
from waiting import wait_until


def scrape(port: int) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    """The simulator's /metrics as {(name, labels): value}."""
    text = httpx.get(f"http://127.0.0.1:{port}/metrics", timeout=5).text
    return {
        (sample.name, tuple(sorted(sample.labels.items()))): sample.value
        for family in text_string_to_metric_families(text)
        for sample in family.samples
    }


def test_the_simulator_process_serves_its_robots_and_stops_on_sigterm() -> None:
    endpoint = free_endpoint()
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        metrics_port = sock.getsockname()[1]
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "robocloud.sim.command",
            "--cloud",
            "cloud-s",
            "--robots",
            "12",
            "--connect",
            endpoint,
            "--seed",
            "3",
            "--speedup",
            "20",
            "--no-churn",
            "--metrics",
            f"127.0.0.1:{metrics_port}",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        # The simulator starts first and waits for its router.
        time.sleep(0.3)
        router = open_router([endpoint])
        link = ZenohRobotLink(router, "cloud-s")
        assert wait_until(lambda: len(link.states()) == 12, timeout=10.0)
        states = link.states()
        assert sorted(states) == [f"s-{i:04d}" for i in range(1, 13)]
        assert {s.kind for s in states.values()} <= {"tribot", "base"}
        idle = next(s for s in states.values() if s.status == "idle" and s.battery > 50)
        here = Assign(
            request_id="r-1",
            location=list(idle.position),
            capabilities=[next(iter(idle.capabilities))],
        )
        assert link.assign(idle.id, here).ok
        busy = next((s for s in states.values() if s.status != "idle"), None)
        if busy is not None:
            assert not link.assign(busy.id, here.model_copy(update={"request_id": "r-2"})).ok
        # Its metrics (docs/metrics.md) say what it did.
        first = scrape(metrics_port)
        robots = {dict(labels)["status"]: v for (name, labels), v in first.items()
                  if name == "robocloud_sim_robots"}
        assert sum(robots.values()) == 12 and robots["idle"] >= 1
        assigned = ("assign", "accepted")
        assert first["robocloud_sim_commands_total", (("command", assigned[0]),
                                                      ("outcome", assigned[1]))] == 1
        if busy is not None:
            assert first["robocloud_sim_commands_total", (("command", "assign"),
                                                          ("outcome", "refused"))] == 1
        published = first["robocloud_sim_states_published_total", ()]
        assert published >= 12
        assert wait_until(
            lambda: scrape(metrics_port)["robocloud_sim_states_published_total", ()] > published,
            timeout=5.0,
        )
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=10) == 0
        link.close()
        router.close()  # type: ignore[no-untyped-call]
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert "simulating 12 robots of cloud-s" in (process.stderr.read() if process.stderr else "")


def test_arguments_and_errors(capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    add_sim_arguments(parser)
    args = parser.parse_args(
        ["--cloud", "cloud-a", "--connect", "tcp/127.0.0.1:1", "--connect-timeout", "0"]
    )
    assert (args.robots, args.seed, args.speedup, args.churn) == (20, 0, 1.0, True)
    with pytest.raises(InvalidInput, match=r"cannot open a Zenoh session on tcp/127\.0\.0\.1:1"):
        sim_command(args)
    code = main(["--cloud", "cloud-a", "--robots", "0", "--connect", "tcp/127.0.0.1:1"])
    assert code == 2
    assert "robocloud: robots must be at least 1" in capsys.readouterr().err
    assert args.gateway is None
    code = main(["--cloud", "cloud-a", "--gateway", "a/b", "--connect", "tcp/127.0.0.1:1"])
    assert code == 2
    assert "robocloud: gateway 'a/b' cannot be used in a Zenoh key" in capsys.readouterr().err
    for bad in ("0", "nan", "101"):
        code = main(["--cloud", "cloud-a", "--no-churn", "--recharge-below", bad,
                     "--connect", "tcp/127.0.0.1:1"])
        assert code == 2
        assert "--recharge-below must be a battery percentage above 0 and at most 100" in (
            capsys.readouterr().err)
