"""The validator rejects each kind of broken plan, with a sentence naming the rule."""

from __future__ import annotations

import copy
import math
from typing import Any

import pytest

from robocloud.planning.validate import check_mission, check_mrta

# Depot at (0, 0); task 1 at (3, 4), 5 away; task 2 at (6, 8), 10 away; end depot at (0, 0).
LOCATIONS = [[0, 0], [3, 4], [6, 8], [0, 0]]
INSTANCE: dict[str, Any] = {
    "Q": [[1, 1], [1, 1], [1, 0]],
    "R": [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [0.0, 0.0]],
    "T_e": [0, 10, 10, 0],
    "T_t": [[math.dist(a, b) for b in LOCATIONS] for a in LOCATIONS],
    "task_locations": LOCATIONS,
    "precedence_constraints": None,
}


def entry(task: int, start: float) -> dict[str, float]:
    return {"task": task, "start_time": start, "end_time": start + 10}


VALID: dict[str, Any] = {
    "makespan": 30.0,
    "n_tasks": 2,
    "n_robots": 3,
    "robot_schedules": {"0": [entry(1, 5.0)], "1": [entry(2, 10.0)], "2": []},
}


def broken(**lists: list[dict[str, float]]) -> dict[str, Any]:
    schedule = copy.deepcopy(VALID)
    for robot, tasks in lists.items():
        schedule["robot_schedules"][robot.removeprefix("r")] = tasks
    return schedule


def test_a_valid_schedule_passes() -> None:
    assert check_mrta(INSTANCE, VALID) == []


@pytest.mark.parametrize(
    ("schedule", "instance_change", "words"),
    [
        (broken(r0=[entry(1, 5.0), entry(2, 12.0)], r1=[]), {}, "at once"),
        (broken(r1=[entry(2, 9.0)]), {}, "cannot reach task 2"),
        (VALID, {"precedence_constraints": [[2, 1]]}, "task 1 starts before task 2"),
        (broken(r2=[entry(1, 6.0)]), {}, "do not start it together"),
        (broken(r1=[], r2=[entry(2, 10.0)]), {}, "needs skill 1, which no member has"),
        (broken(r2=[entry(1, 5.0)]), {}, "passenger"),
        (broken(r1=[]), {}, "task 2 is not done"),
        ({**VALID, "makespan": 25.0}, {}, "makespan is stated as 25"),
        (broken(r0=[{"task": 1, "start_time": 5.0, "end_time": 9.0}]), {}, "lasts 4"),
    ],
    ids=["overlap", "travel", "precedence", "unsynchronised", "skill", "passenger",
         "missing", "makespan", "duration"],
)
def test_each_broken_rule_is_named(
    schedule: dict[str, Any], instance_change: dict[str, Any], words: str
) -> None:
    problems = check_mrta({**INSTANCE, **instance_change}, schedule)
    assert any(words in p for p in problems), problems


ROBOT = {"cloud": "c", "battery": 90.0, "status": "idle", "travel_cost_per_m": 1.0}


def robot(name: str, x: float, capabilities: dict[str, float]) -> dict[str, Any]:
    return {**ROBOT, "id": name, "position": [x, 0.0], "speed": 2.0,
            "capabilities": {c: {"kind": "sensing", "time": t, "cost": 1.0}
                             for c, t in capabilities.items()}}


MISSION: dict[str, Any] = {
    "robots": [robot("a", 0.0, {"light": 10.0}), robot("b", 0.0, {"light": 20.0}),
               robot("c", 0.0, {"sound": 5.0})],
    "mission": {"tasks": [{"id": "f1", "location": [10.0, 0.0], "sensing": {"light": 2}},
                          {"id": "f2", "location": [20.0, 0.0], "sensing": {"sound": 1}}],
                "precedence": [["f1", "f2"]], "end": [0.0, 0.0]},
}
# a and b drive 10 m at 2 m/s (5 s), f1 lasts b's 20 s: 5 to 25; c reaches f2 at 10 s but
# waits for f1: 25 to 30; then home, 10 s for c (20 m), 5 s for a and b.
PLAN: dict[str, Any] = {
    "makespan": 40.0,
    "cost": 10 + 10 + 20 + 40 + 3,
    "tasks": [{"id": "f1", "robots": ["a", "b"], "start": 5.0, "end": 25.0},
              {"id": "f2", "robots": ["c"], "start": 25.0, "end": 30.0}],
    "routes": {"a": [{"task": "f1", "start": 5.0}], "b": [{"task": "f1", "start": 5.0}],
               "c": [{"task": "f2", "start": 25.0}]},
}


def test_a_valid_mission_plan_passes() -> None:
    assert check_mission(MISSION, PLAN) == []


def test_a_mission_plan_short_of_a_count_or_too_early_is_refused() -> None:
    short = copy.deepcopy(PLAN)
    short["tasks"][0]["robots"] = ["a"]
    short["routes"]["b"] = []
    assert any("needs 2 robots with light, has 1" in p for p in check_mission(MISSION, short))
    early = copy.deepcopy(PLAN)
    early["tasks"][1].update(start=20.0, end=25.0)
    early["routes"]["c"][0]["start"] = 20.0
    assert any("f2 starts before task f1" in p for p in check_mission(MISSION, early))
    quick = copy.deepcopy(PLAN)
    quick["tasks"][0]["end"] = 20.0
    assert any("slowest member" in p for p in check_mission(MISSION, quick))
