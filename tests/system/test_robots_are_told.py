"""Robots are always told: faults of robots written from the README alone, against a real IaaS.

A late acknowledgement, a robot back from a crash still holding its task, and
an IaaS killed while its robot finishes. The robots are ``ReadmeRobot``s
(zenoh and json only), not the simulator.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import pytest
from processes import Cloud, follow, wait_until
from readme_fleet import details, join, leave
from readme_robot import ReadmeRobot

pytestmark = pytest.mark.slow

TASK: dict[str, Any] = {
    "location": [20.0, 0.0],
    "actuating": {"grabber": 1},
    "max_robots": 1,
    "max_cost": 100.0,
    "max_time": 100.0,
    "priority": "time",
}


@pytest.fixture(scope="module")
def cloud(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cloud]:
    """One IaaS for the file: each test has robots of its own (ids not used elsewhere);
    a test that kills the IaaS starts it again."""
    tmp_path = tmp_path_factory.mktemp("robots-are-told")
    cloud = Cloud(
        "cloud-a",
        tmp_path,
        f"sqlite:///{tmp_path / 'cloud-a.db'}",
        robots=0,
        speedup=1.0,
        iaas_args=[
            "--ack-timeout", "1", "--offline-after", "1.5", "--log-level", "info",
            # A robot or two to choose from: the selection runs in the IaaS's
            # thread, without the worker processes a start would fork first.
            "--selection-workers", "0",
        ],
    )  # fmt: skip
    try:
        yield cloud.start()
    finally:
        cloud.stop()


@pytest.fixture
def robots(cloud: Cloud) -> Iterator[list[ReadmeRobot]]:
    made: list[ReadmeRobot] = []
    yield made
    leave(cloud, made)  # not chosen by the next test


def test_a_late_acknowledgement_is_canceled_and_one_robot_does_the_job(
    cloud: Cloud, robots: list[ReadmeRobot]
) -> None:
    late = join(cloud, robots, "a-late", 18.0, ack_delay=2.5)  # the best choice: closest
    # 0.2 s to drive at 100 m/s and 2.5 s of work: slower than a-late's 2.2 s, so second.
    slower = {"grabber": {"kind": "actuating", "time": 2.5, "cost": 1.0}}
    good = join(cloud, robots, "a-good", 0.0, capabilities=slower, speed=100.0)
    with cloud.client() as client:
        rid = client.post("/v1/requests", json=TASK).json()["id"]
        done = follow(client, rid, lambda r: r["state"] in ("completed", "failed"), 30, "the end")
    assert done["state"] == "completed", done
    assert [a["robot"] for a in done["coalition"]] == ["a-good"]
    assert any(
        d.startswith("robot a-late did not answer within the ack deadline (1 s); ")
        for d in details(done)
    ), details(done)
    # The late robot was told to stop, and never did the job.
    assert late.commands_for(rid, "cancel"), late.commands
    wait_until(lambda: late.task is None or late.task["phase"] == "done", 5, "a-late to stop")
    assert not any(
        s["task"] and s["task"]["request_id"] == rid and s["task"]["phase"] == "done"
        for s in late.states
    ), "the late robot did the job too"
    assert good.last_task is not None and good.last_task["request_id"] == rid


def test_a_robot_back_from_a_crash_is_told_to_stop_within_a_second(
    cloud: Cloud, robots: list[ReadmeRobot]
) -> None:
    crashing = join(cloud, robots, "a-crash", 18.0, speed=1.0)  # a long trip: 2 s... at 1 m/s
    join(cloud, robots, "a-spare", 0.0)
    with cloud.client() as client:
        rid = client.post("/v1/requests", json=TASK).json()["id"]
        follow(client, rid, lambda r: r["state"] == "underway", 10, "underway")
        crashing.silent()
        replaced = follow(
            client,
            rid,
            lambda r: any("replaced by a-spare" in d for d in details(r)),
            15,
            "a-crash to be replaced",
        )
        assert any("robot a-crash failed: it has been silent" in d for d in details(replaced))
        assert crashing.task is not None and crashing.task["request_id"] == rid  # still on it
        back_at = time.monotonic()
        crashing.back()
        told = wait_until(
            lambda: [t for t in crashing.commands_for(rid, "cancel") if t >= back_at],
            5,
            "a-crash to be told to stop",
        )
        assert told[0] - back_at <= 1.0, f"told {told[0] - back_at:.2f} s after it was back"
        wait_until(lambda: crashing.task is None, 2, "a-crash to stop")
        done = follow(client, rid, lambda r: r["state"] in ("completed", "failed"), 30, "the end")
        assert done["state"] == "completed", done
        robots_now = {r["id"]: r for r in client.get("/v1/robots").json()}
        assert robots_now["a-crash"]["status"] == "idle"
        assert robots_now["a-crash"]["request"] is None


def test_a_robot_that_finishes_while_the_iaas_is_down_completes_the_request(
    cloud: Cloud, robots: list[ReadmeRobot]
) -> None:
    # 20 m at 10 m/s, then 0.5 s of work: done 2.5 s after the assign, well after the kill;
    # the finished task stays in its state for 1 s.
    quick = {"grabber": {"kind": "actuating", "time": 0.5, "cost": 1.0}}
    robot = join(cloud, robots, "a-1", 0.0, capabilities=quick, keep_done=1.0)
    with cloud.client() as client:
        rid = client.post("/v1/requests", json=TASK).json()["id"]
        follow(client, rid, lambda r: r["state"] == "underway", 10, "underway")
    cloud.kill_iaas()
    wait_until(lambda: robot.last_task and robot.last_task["request_id"] == rid, 10, "done")
    # Past the second a finished task stays in the state: only last_task tells now.
    wait_until(lambda: robot.task is None, 6, "the finished task to leave the state")
    cloud.start_iaas()
    with cloud.client() as client:
        done = follow(client, rid, lambda r: r["state"] in ("completed", "failed"), 20, "the end")
    assert done["state"] == "completed", done
    assert any("restart" in d for d in details(done))
