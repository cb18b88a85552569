"""The accepted ranges of the domain's numbers and names: absurd values are refused by field."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from robocloud.domain import Robot, Task
from robocloud.fleet.messages import State

TASK = {
    "location": [400.0, 310.0],
    "actuating": {"grabber": 2},
    "max_robots": 5,
    "max_cost": 500.0,
    "max_time": 600.0,
}
ROBOT = {
    "id": "a-0001",
    "cloud": "cloud-a",
    "position": [1.0, 2.0],
    "speed": 1.5,
    "battery": 80.0,
    "status": "idle",
    "travel_cost_per_m": 0.05,
    "capabilities": {"grabber": {"kind": "actuating", "time": 90.0, "cost": 8.0}},
}


def field_of(error: ValidationError) -> str:
    return ".".join(str(part) for part in error.errors()[0]["loc"])


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"location": [1e308, -1e308]}, "location.0"),
        ({"location": [0.0, -1.5e7]}, "location.1"),
        ({"max_cost": 1e300}, "max_cost"),
        ({"max_time": 1e300}, "max_time"),
        ({"actuating": {"grabber": 1001}}, "actuating.grabber"),
        ({"actuating": {"grab\x00ber": 1}}, "actuating.grab\x00ber.[key]"),
        ({"max_robots": 100_001}, "max_robots"),
        ({"actuating": {f"g{i}": 1 for i in range(101)}}, "actuating"),
    ],
)
def test_an_absurd_task_is_refused_naming_the_field(change: dict[str, object], field: str) -> None:
    with pytest.raises(ValidationError) as caught:
        Task.model_validate({**TASK, **change})
    assert field_of(caught.value) == field


def test_the_bounds_themselves_are_accepted() -> None:
    task = Task.model_validate(
        {
            **TASK,
            "location": [1e7, -1e7],
            "max_cost": 1e12,
            "max_time": 1e9,
            "actuating": {"grabber": 1000},
            "max_robots": 100_000,
        }
    )
    assert task.required == {"grabber": 1000}
    hundred = Task.model_validate(
        {**TASK, "sensing": {f"s{i}": 1 for i in range(50)},
         "actuating": {f"a{i}": 1 for i in range(50)}}
    )
    assert len(hundred.required) == 100


def test_at_most_a_hundred_capabilities_in_all_sensing_and_actuating_together() -> None:
    with pytest.raises(ValidationError) as caught:
        Task.model_validate(
            {**TASK, "sensing": {f"s{i}": 1 for i in range(50)},
             "actuating": {f"a{i}": 1 for i in range(51)}}
        )
    assert "at most 100 capabilities, sensing and actuating together, not 101" in str(
        caught.value
    )


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"speed": 1e-300}, "speed"),
        ({"speed": 1e6}, "speed"),
        ({"id": "a-\x000"}, "id"),
        ({"cloud": "cloud\n-a"}, "cloud"),
        ({"position": [float("inf"), 0.0]}, "position.0"),
        ({"travel_cost_per_m": 1e100}, "travel_cost_per_m"),
    ],
)
def test_an_absurd_robot_is_refused_naming_the_field(change: dict[str, object], field: str) -> None:
    with pytest.raises(ValidationError) as caught:
        Robot.model_validate({**ROBOT, **change})
    assert field_of(caught.value) == field
    state = {**ROBOT, **change, "kind": "tribot", "seq": 1, "sent_at": 0.0}
    with pytest.raises(ValidationError):
        State.model_validate(state)


def test_a_state_keeps_its_last_finished_task() -> None:
    state = State.model_validate(
        {
            **ROBOT,
            "kind": "tribot",
            "seq": 1,
            "sent_at": 0.0,
            "last_task": {
                "request_id": "req-x",
                "phase": "done",
                "progress": 1.0,
                "capabilities": ["grabber"],
            },
        }
    )
    assert state.last_task is not None and state.last_task.request_id == "req-x"
    plain = State.model_validate({**ROBOT, "kind": "tribot", "seq": 1, "sent_at": 0.0})
    assert plain.last_task is None
