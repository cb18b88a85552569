"""``python -m robocloud.sim.command`` as a process, connected to the test's router."""

import argparse
import signal
import subprocess
import sys
import time

import pytest
from sim_testing import free_endpoint, wait_until

from robocloud.errors import InvalidInput
from robocloud.fleet import Assign, ZenohRobotLink, open_router
from robocloud.sim.command import add_sim_arguments, main, sim_command


def test_the_simulator_process_serves_its_robots_and_stops_on_sigterm() -> None:
    endpoint = free_endpoint()
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
    assert "error: robots must be at least 1" in capsys.readouterr().err
    assert args.gateway is None
    code = main(["--cloud", "cloud-a", "--gateway", "a/b", "--connect", "tcp/127.0.0.1:1"])
    assert code == 2
    assert "error: gateway 'a/b' cannot be used in a Zenoh key" in capsys.readouterr().err
