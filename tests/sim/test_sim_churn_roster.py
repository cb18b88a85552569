from collections import Counter

import numpy as np
import pytest

from robocloud.errors import InvalidInput
from robocloud.sim.churn import Churn
from robocloud.sim.robot import SimRobot
from robocloud.sim.roster import cloud_letter, cloud_robots


def test_roster_names_robots_by_cloud_and_gives_kinds() -> None:
    fleet = cloud_robots("cloud-b", 40, seed=3)
    assert [r["id"] for r in fleet[:2]] == ["b-0001", "b-0002"]
    assert {r["cloud"] for r in fleet} == {"cloud-b"}
    assert {r["kind"] for r in fleet} == {"tribot", "base"}
    for robot in fleet:
        actuator = "grabber" if robot["kind"] == "tribot" else "kicker"
        assert robot["capabilities"][actuator]["kind"] == "actuating"
        assert all(0.0 <= v <= 2000.0 for v in robot["position"])
    assert cloud_robots("cloud-b", 40, seed=3) == fleet
    assert cloud_robots("cloud-c", 40, seed=3)[0]["position"] != fleet[0]["position"]
    assert SimRobot.from_json(fleet[0]).kind == fleet[0]["kind"]


def test_cloud_letters() -> None:
    assert cloud_letter("cloud-b") == "b"
    assert cloud_letter("Acme") == "a"
    assert cloud_letter("-9x") == "9"
    with pytest.raises(InvalidInput):
        cloud_letter("---")
    with pytest.raises(InvalidInput):
        cloud_robots("a/b", 3)


def fleet(n: int = 400) -> list[SimRobot]:
    return [SimRobot.from_json(r) for r in cloud_robots("cloud-a", n, seed=1)]


def test_without_churn_statuses_stay_as_drawn() -> None:
    robots = fleet()
    churn = Churn(np.random.default_rng(0), enabled=False)
    for robot in robots:
        churn.adopt(robot)
    before = [(r.status, r.battery) for r in robots]
    for _ in range(50):
        churn.step(robots, 100.0)
        for robot in robots:
            robot.advance(100.0, 0.0)
    assert [(r.status, r.battery) for r in robots] == before


def test_churn_keeps_the_shares_near_the_scenario() -> None:
    robots = fleet()
    churn = Churn(np.random.default_rng(0))
    for robot in robots:
        churn.adopt(robot)
    shares: Counter[str] = Counter()
    for step in range(1500):
        churn.step(robots, 5.0)
        for robot in robots:
            robot.advance(5.0, 0.0)
        if step >= 500:
            shares.update(r.status for r in robots)
    total = sum(shares.values())
    share = {status: count / total for status, count in shares.items()}
    assert share["idle"] == pytest.approx(0.25, abs=0.06)
    assert share["busy"] == pytest.approx(0.30, abs=0.07)
    for status in ("reserved", "charging", "offline"):
        assert share[status] == pytest.approx(0.15, abs=0.06)
    low_idle = [r for r in robots if r.status == "idle" and r.battery < churn.rates.low_battery]
    assert len(low_idle) <= 2  # sent charging at their next step


def test_without_churn_a_low_idle_robot_recharges_and_nothing_else_moves() -> None:
    robots = fleet(60)
    churn = Churn(np.random.default_rng(0), enabled=False, recharge_below=20.0)
    for robot in robots:
        churn.adopt(robot)
    idle = [r for r in robots if r.status == "idle"]
    low, fine = idle[0], idle[1]
    low.battery, fine.battery = 4.0, 25.0
    others = [(r.id, r.status, r.battery) for r in robots if r not in (low, fine)]
    churn.step(robots, 1.0)
    assert low.status == "charging" and fine.status == "idle"
    for _ in range(100):  # 1,000 s: (100 - 4) / 0.1 = 960 s of charging
        for robot in robots:
            robot.advance(10.0, 0.0)
        churn.step(robots, 10.0)
    assert (low.status, low.battery) == ("idle", 100.0)
    assert (fine.status, fine.battery) == ("idle", 25.0)
    assert [(r.id, r.status, r.battery) for r in robots if r not in (low, fine)] == others


def test_a_recharge_threshold_must_be_a_percentage() -> None:
    from robocloud.sim.fleet import FleetSimulator

    with pytest.raises(InvalidInput, match=r"a percentage above 0 and at most 100, not 0\.0"):
        FleetSimulator("cloud-a", cloud_robots("cloud-a", 2), None, recharge_below=0.0)  # type: ignore[arg-type]
