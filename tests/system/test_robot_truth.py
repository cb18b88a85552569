"""What the cloud believes is what the robots do: the watchdog, claims that end, give-ups that stop.

Robots written from the README alone (``ReadmeRobot``: zenoh and json) against
a real IaaS process: a robot that never arrives is stopped and replaced within
its expected time plus the tolerance; a robot that failed and came back serves
the next request at once; every give-up (a robot killed with no replacement, a
cancel while an ack is on its way) ends with a stop that the robot receives;
a robot that never acknowledges is set aside, and ``/v1/robots`` says why.
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
FINAL = ("completed", "failed", "rejected", "canceled")


@pytest.fixture(scope="module")
def cloud(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cloud]:
    """One IaaS for the file: each test has robots of its own (ids not used elsewhere)."""
    tmp_path = tmp_path_factory.mktemp("robot-truth")
    cloud = Cloud(
        "cloud-a",
        tmp_path,
        f"sqlite:///{tmp_path / 'cloud-a.db'}",
        robots=0,
        speedup=1.0,
        iaas_args=[
            "--ack-timeout", "1", "--offline-after", "1.5", "--log-level", "info",
            # The watchdog made short: a robot may run 50% past its expected
            # time, at least 1 s; 3 s without progress is a stall.
            "--overrun-min", "1", "--stall-after", "3", "--set-aside-for", "60",
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


def at(request: dict[str, Any], state: str) -> float:
    """When the request entered ``state`` (unix seconds)."""
    from datetime import datetime

    entry = next(h for h in request["history"] if h["kind"] == "state" and h["state"] == state)
    return datetime.fromisoformat(entry["at"]).timestamp()


def test_a_robot_that_never_arrives_is_stopped_and_replaced_within_its_tolerance(
    cloud: Cloud, robots: list[ReadmeRobot]
) -> None:
    lost = join(cloud, robots, "a-lost", 18.0, never_arrives=True)  # the quickest: chosen
    # 0.2 s to drive and 2.5 s of work: slower than a-lost's 2.2 s, quicker than 4 s at 10 m/s.
    later = {"grabber": {"kind": "actuating", "time": 2.5, "cost": 1.0}}
    join(cloud, robots, "a-spare", 0.0, capabilities=later, speed=100.0)
    with cloud.client() as client:
        rid = client.post("/v1/requests", json=TASK).json()["id"]
        done = follow(client, rid, lambda r: r["state"] in FINAL, 30, "the end")
    assert done["state"] == "completed", done
    assert [a["robot"] for a in done["coalition"]] == ["a-spare"]
    failure = next(d for d in details(done) if d.startswith("robot a-lost failed"))
    # a-lost: 2 m at 10 m/s and 2 s of work, 2.2 s; tolerance: the larger of 1.1 s and 1 s.
    assert "it is past its expected finish (2 s robot time, plus 1 s of tolerance)" in failure
    assert any("replaced by a-spare" in d for d in details(done))
    # It kept reporting progress all along; the watchdog gave it no more time for that.
    stopped_after = lost.commands_for(rid, "cancel")[0] - lost.commands_for(rid, "assign")[0]
    assert 3.3 - 0.2 < stopped_after < 3.3 + 1.5, stopped_after
    wait_until(lambda: lost.task is None, 2, "a-lost to stop")
    assert at(done, "completed") - at(done, "dispatched") < TASK["max_time"] + 50


def test_a_robot_that_failed_and_came_back_serves_the_next_request(
    cloud: Cloud, robots: list[ReadmeRobot]
) -> None:
    flaky = join(cloud, robots, "a-flaky", 18.0)
    slow = {"grabber": {"kind": "actuating", "time": 8.0, "cost": 1.0}}
    join(cloud, robots, "a-spare2", 0.0, capabilities=slow)
    with cloud.client() as client:
        first = client.post("/v1/requests", json=TASK).json()["id"]
        follow(client, first, lambda r: r["state"] == "underway", 10, "underway")
        flaky.silent()
        follow(
            client,
            first,
            lambda r: any("replaced by a-spare2" in d for d in details(r)),
            10,
            "a-flaky to be replaced",
        )
        flaky.back()  # told to stop: its request has another robot now
        wait_until(lambda: flaky.task is None, 5, "a-flaky to stop")
        wait_until(
            lambda: {r["id"]: r for r in client.get("/v1/robots").json()}["a-flaky"]["status"]
            == "idle",
            5,
            "a-flaky idle",
        )
        # a-spare2 still works for the first request: only a-flaky can serve the second.
        second = client.post("/v1/requests", json=TASK).json()["id"]
        done = follow(client, second, lambda r: r["state"] in FINAL, 20, "the second's end")
        assert done["state"] == "completed", done
        assert [a["robot"] for a in done["coalition"]] == ["a-flaky"]
        assert client.get(f"/v1/requests/{first}").json()["state"] in ("underway", "completed")


def test_a_robot_killed_with_no_replacement_is_told_to_stop_when_it_is_back(
    cloud: Cloud, robots: list[ReadmeRobot]
) -> None:
    only = join(cloud, robots, "a-only", 0.0, speed=2.0)  # 10 s of travel
    with cloud.client() as client:
        rid = client.post("/v1/requests", json=TASK).json()["id"]
        follow(client, rid, lambda r: r["state"] == "underway", 10, "underway")
        only.silent()
        failed = follow(client, rid, lambda r: r["state"] in FINAL, 10, "the end")
    assert failed["state"] == "failed", failed
    assert "no replacement was found" in (failed["reason"] or "")
    assert only.task is not None and only.task["request_id"] == rid  # it did not hear the stop
    back_at = time.monotonic()
    only.back()
    told = wait_until(
        lambda: [t for t in only.commands_for(rid, "cancel") if t >= back_at],
        5,
        "a-only to be told to stop",
    )
    assert told[0] - back_at <= 1.5
    wait_until(lambda: only.task is None, 2, "a-only to stop")


def test_a_cancel_while_the_ack_is_on_its_way_ends_with_a_stop_the_robot_received(
    cloud: Cloud, robots: list[ReadmeRobot]
) -> None:
    robot = join(cloud, robots, "a-slowack", 0.0, ack_delay=0.6)  # within the 1 s deadline
    with cloud.client() as client:
        rid = client.post("/v1/requests", json=TASK).json()["id"]
        wait_until(lambda: robot.commands_for(rid, "assign"), 5, "the assign to arrive")
        canceled = client.post(f"/v1/requests/{rid}/cancel").json()
    assert canceled["state"] == "canceled", canceled
    wait_until(lambda: robot.commands_for(rid, "cancel"), 5, "the robot to be told to stop")
    wait_until(lambda: robot.task is None, 3, "the robot to stop")


def test_a_robot_that_never_acknowledges_is_set_aside_and_the_reason_says_so(
    cloud: Cloud, robots: list[ReadmeRobot]
) -> None:
    quick = {"grabber": {"kind": "actuating", "time": 0.5, "cost": 1.0}}
    deaf = join(cloud, robots, "a-deaf", 18.0, quick, ack_delay=2.5)  # past the 1 s ack deadline
    # Slower at the work (1 s) than a-deaf (0.7 s) wherever it is: a-deaf is the first
    # choice each time; 0.2 s to drive at 100 m/s.
    slower = {"grabber": {"kind": "actuating", "time": 1.0, "cost": 1.0}}
    join(cloud, robots, "a-good", 0.0, capabilities=slower, speed=100.0)
    with cloud.client() as client:
        for attempt in (1, 2):
            rid = client.post("/v1/requests", json=TASK).json()["id"]
            done = follow(client, rid, lambda r: r["state"] in FINAL, 30, f"request {attempt}")
            assert done["state"] == "completed", done
            assert any(
                d.startswith("robot a-deaf did not answer within the ack deadline (1 s); ")
                for d in details(done)
            ), details(done)
            assert not any("a-deaf refused" in d for d in details(done))
            wait_until(
                lambda: {r["id"]: r for r in client.get("/v1/robots").json()}["a-good"]["status"]
                == "idle",
                10,
                "a-good to be idle again",
            )
            # a-deaf answers 2.5 s after the assign, late, and then hears the stop: idle
            # again, and so the first choice of the next request.
            wait_until(
                lambda rid=rid: any(
                    s["task"] and s["task"]["request_id"] == rid for s in deaf.states
                )
                and deaf.task is None
                and {r["id"]: r for r in client.get("/v1/robots").json()}["a-deaf"]["status"]
                == "idle",
                10,
                "a-deaf to be idle again",
            )
        listed = {r["id"]: r for r in client.get("/v1/robots").json()}
        aside = listed["a-deaf"]["set_aside"]
        assert aside is not None, listed["a-deaf"]
        assert aside["why"].startswith("it failed 2 requests in a row: robot a-deaf did not answer")
        assert listed["a-good"]["set_aside"] is None
        # Not tried a third time: the next request goes to a-good at once.
        rid = client.post("/v1/requests", json=TASK).json()["id"]
        done = follow(client, rid, lambda r: r["state"] in FINAL, 30, "request 3")
        assert done["state"] == "completed"
        assert not any("a-deaf" in d for d in details(done)), details(done)
        metrics = {
            line.rsplit(" ", 1)[0]: float(line.rsplit(" ", 1)[1])
            for line in client.get("/metrics").text.splitlines()
            if line and not line.startswith("#")
        }
        # The cloud is shared by this file's tests: at least these.
        assert metrics["robocloud_robots_set_aside_total"] >= 1
        assert metrics['robocloud_robot_failures_total{cause="no_ack"}'] >= 2
