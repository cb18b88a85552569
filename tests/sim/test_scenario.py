"""The thesis's wildfire scenario (section 5.4): shape, shares, determinism, feasibility."""

import re
import time
from collections import Counter

import numpy as np
import pytest

from robocloud.domain import Robot, Task
from robocloud.errors import InvalidInput
from robocloud.selection.filtering import filter_robots
from robocloud.selection.pipeline import select
from robocloud.selection.problem import robot_terms
from robocloud.sim.scenario import (
    FOREST_SIZE,
    SENSORS,
    cloud_names,
    wildfire_robots,
    wildfire_scenario,
    wildfire_task,
)

ID = re.compile(r"^([a-z])-(\d{4,})$")


def parsed(robots: int = 1000, clouds: int = 3, seed: int = 0) -> tuple[list[Robot], Task]:
    scenario = wildfire_scenario(robots, clouds, seed)
    return (
        [Robot.model_validate(r) for r in scenario["robots"]],
        Task.model_validate(scenario["task"]),
    )


def test_same_seed_same_scenario() -> None:
    assert wildfire_scenario(300, 3, 7) == wildfire_scenario(300, 3, 7)


def test_another_seed_another_scenario() -> None:
    assert wildfire_scenario(300, 3, 7) != wildfire_scenario(300, 3, 8)


def test_the_task_does_not_depend_on_the_fleet_size() -> None:
    assert wildfire_scenario(10, 1, 5)["task"] == wildfire_scenario(500, 4, 5)["task"]


def test_shape_count_clouds_and_ids() -> None:
    robots = wildfire_robots(1000, 3, 0)
    assert len(robots) == 1000
    per_cloud = Counter(r["cloud"] for r in robots)
    assert set(per_cloud) == {"cloud-a", "cloud-b", "cloud-c"}
    assert max(per_cloud.values()) - min(per_cloud.values()) <= 1
    ids = [r["id"] for r in robots]
    assert len(set(ids)) == len(ids)
    for robot in robots:
        match = ID.match(robot["id"])
        assert match, robot["id"]
        assert robot["cloud"] == f"cloud-{match.group(1)}"
    assert "a-0001" in ids and "c-0333" in ids


def test_cloud_names_run_through_the_alphabet() -> None:
    assert cloud_names(1) == ["cloud-a"]
    assert cloud_names(26)[-1] == "cloud-z"
    robots = wildfire_robots(52, 26, 1)
    assert {r["cloud"] for r in robots} == set(cloud_names(26))


def test_ids_widen_past_9999_robots_a_cloud() -> None:
    ids = [r["id"] for r in wildfire_robots(10_000, 1, 0)]
    assert ids[0] == "a-00001" and ids[-1] == "a-10000"


def test_every_robot_and_the_task_validate() -> None:
    robots, task = parsed()
    assert len(robots) == 1000
    assert task.priority == "time"
    assert task.execution == "parallel"
    assert (task.max_robots, task.max_cost, task.max_time, task.min_battery) == (50, 500, 600, 70)
    assert task.sensing == {"light": 1, "ultrasonic": 1}
    assert task.actuating == {"grabber": 2, "kicker": 1}
    assert all(0 <= v <= FOREST_SIZE for v in task.location)


def test_about_one_in_ten_robots_meets_the_filter() -> None:
    robots, _ = parsed()
    ready = [r for r in robots if r.status == "idle" and r.battery >= 70]
    assert 60 <= len(ready) <= 140
    statuses = Counter(r.status for r in robots)
    assert set(statuses) == {"idle", "busy", "charging", "reserved", "offline"}
    # Idle robots below the filter exist too, so the battery rule matters.
    assert any(r.status == "idle" and r.battery < 70 for r in robots)


def test_nxt_like_robots_with_varied_sensors() -> None:
    robots, _ = parsed()
    sensor_sets = set()
    for robot in robots:
        actuators = {n for n, c in robot.capabilities.items() if c.kind == "actuating"}
        sensors = {n for n, c in robot.capabilities.items() if c.kind == "sensing"}
        assert actuators in ({"grabber"}, {"kicker"})
        assert sensors and sensors <= set(SENSORS)
        sensor_sets.add(frozenset(sensors))
        assert 0.5 <= robot.speed <= 2.0
        assert 0.02 <= robot.travel_cost_per_m <= 0.1
        assert all(0 <= v <= FOREST_SIZE for v in robot.position)
        for capability in robot.capabilities.values():
            if capability.kind == "sensing":
                assert 10 <= capability.time <= 60 and 0.5 <= capability.cost <= 3
            else:
                assert 60 <= capability.time <= 180 and 4 <= capability.cost <= 15
    assert len(sensor_sets) >= 10


@pytest.mark.parametrize("seed", range(5))
def test_some_candidates_reach_the_fire_in_time(seed: int) -> None:
    robots, task = parsed(seed=seed)
    candidates = filter_robots(robots, task)
    terms = robot_terms(candidates, task)
    in_time = (terms.time <= task.max_time) & (terms.cost <= task.max_cost)
    brings = terms.uses[in_time].sum(axis=0)
    need = np.array(list(task.required.values()))
    assert (brings >= need).all(), dict(zip(terms.capabilities, brings, strict=True))


@pytest.mark.parametrize("seed", range(3))
def test_the_thesis_request_is_feasible_with_several_trade_offs(seed: int) -> None:
    robots, task = parsed(seed=seed)
    result = select(robots, task, optimizer="exact")
    assert result.candidates == 100
    assert result.chosen is not None
    assert len(result.pareto) >= 2
    times = {round(c.time, 6) for c in result.pareto}
    costs = {round(c.cost, 6) for c in result.pareto}
    assert len(times) >= 2 and len(costs) >= 2


def test_seed_0_front_trades_size_too() -> None:
    robots, task = parsed(seed=0)
    result = select(robots, task, optimizer="exact")
    assert len(result.pareto) >= 3
    assert len({c.size for c in result.pareto}) >= 2


def test_a_hundred_thousand_robots_keep_the_shape_and_are_quick() -> None:
    start = time.perf_counter()
    robots = wildfire_robots(100_000, 3, 0)
    elapsed = time.perf_counter() - start
    assert len(robots) == 100_000
    ready = sum(1 for r in robots if r["status"] == "idle" and r["battery"] >= 70)
    assert ready == 10_000
    assert all(0 <= r["position"][0] <= FOREST_SIZE for r in robots)
    # A couple of seconds on a laptop; generous here so a busy machine passes.
    assert elapsed < 10


@pytest.mark.parametrize(
    ("robots", "clouds", "seed", "field"),
    [
        (0, 3, 0, "robots"),
        (-1, 3, 0, "robots"),
        (10, 0, 0, "clouds"),
        (10, 27, 0, "clouds"),
        (10, 3, -1, "seed"),
    ],
)
def test_bad_arguments_are_invalid_input(robots: int, clouds: int, seed: int, field: str) -> None:
    with pytest.raises(InvalidInput) as caught:
        wildfire_scenario(robots, clouds, seed)
    assert caught.value.field == field
    assert field in str(caught.value)


def test_task_alone_matches_the_scenario() -> None:
    assert wildfire_task(3) == wildfire_scenario(20, 2, 3)["task"]
