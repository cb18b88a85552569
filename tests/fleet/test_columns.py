"""The fleet as columns: the filter and the terms a selection reads equal the Robot path's.

``candidates`` over ``LatestStates.columns()`` must give, bit for bit, the
``CoalitionProblem`` that ``filter_robots`` and ``CoalitionProblem.build``
give over ``LatestStates.robots()`` (reserved robots marked, as
``FederationView.local_robots`` does), followed by other clouds' robots.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from robocloud.domain import Robot, Task
from robocloud.fleet.link import LatestStates
from robocloud.fleet.messages import State
from robocloud.selection.columns import candidates
from robocloud.selection.filtering import filter_robots
from robocloud.selection.problem import CoalitionProblem

KINDS = {"light": "sensing", "sound": "sensing", "grabber": "actuating", "kicker": "actuating"}
OFFLINE_AFTER = 5.0


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@st.composite
def capabilities(draw: st.DrawFn) -> dict[str, dict[str, Any]]:
    names = draw(st.sets(st.sampled_from(sorted(KINDS)), max_size=3))
    return {
        name: {
            "kind": KINDS[name],
            "time": draw(st.sampled_from([0.0, 1.5, 7.0, draw(st.floats(0, 60))])),
            "cost": draw(st.floats(0, 10)),
        }
        for name in names
    }


@st.composite
def robot_fields(draw: st.DrawFn, rid: str, cloud: str) -> dict[str, Any]:
    return {
        "id": rid,
        "cloud": cloud,
        "position": [draw(st.floats(-100, 100)), draw(st.floats(-100, 100))],
        "speed": draw(st.floats(0.5, 3)),
        "battery": draw(st.sampled_from([0.0, 20.0, 50.0, draw(st.floats(0, 100))])),
        "status": draw(st.sampled_from(["idle", "idle", "idle", "busy", "charging", "offline"])),
        "travel_cost_per_m": draw(st.floats(0, 0.2)),
        "capabilities": draw(capabilities()),
    }


def state(fields: dict[str, Any], seq: int) -> State:
    return State.model_validate(
        {**fields, "kind": "tribot", "task": None, "seq": seq, "sent_at": float(seq)}
    )


@st.composite
def fleets(draw: st.DrawFn) -> tuple[LatestStates, list[str], list[Robot], Task]:
    """A fleet heard over time (some robots change, some fall silent), a task, exclusions."""
    clock = Clock()
    latest = LatestStates("cloud-a", OFFLINE_AFTER, clock)
    n = draw(st.integers(0, 14))
    ids = [f"a-{i:02d}" for i in draw(st.permutations(range(n)))]
    shared = draw(capabilities())
    for seq in range(1, draw(st.integers(1, 3)) + 1):
        # Robots heard this round; a robot left out now and then falls silent.
        for rid in ids:
            if seq == 1 or draw(st.booleans()):
                fields = draw(robot_fields(rid, "cloud-a"))
                if draw(st.booleans()):
                    fields["capabilities"] = shared
                latest.accept(state(fields, seq))
        clock.now += draw(st.sampled_from([0.5, 3.0, OFFLINE_AFTER + 1]))
    excluded = draw(st.lists(st.sampled_from([*ids, "a-99"]), max_size=4)) if ids else []
    others = [
        Robot.model_validate(draw(robot_fields(f"b-{i}", "cloud-b")))
        for i in range(draw(st.integers(0, 3)))
    ]
    wanted = draw(st.sets(st.sampled_from(sorted(KINDS)), min_size=1, max_size=3))
    counts = {name: draw(st.integers(1, 2)) for name in sorted(wanted)}
    task = Task(
        location=[draw(st.floats(-50, 50)), 10.0],
        sensing={k: v for k, v in counts.items() if KINDS[k] == "sensing"},
        actuating={k: v for k, v in counts.items() if KINDS[k] == "actuating"},
        max_robots=3,
        max_cost=100.0,
        max_time=500.0,
        min_battery=draw(st.sampled_from([0.0, 20.0, 50.0])),
        execution=draw(st.sampled_from(["parallel", "sequential"])),
    )
    return latest, excluded, others, task


def expected(
    latest: LatestStates, excluded: list[str], others: list[Robot], task: Task
) -> CoalitionProblem:
    """What the Robot path gives: ``local_robots`` then ``filter_robots`` and ``build``."""
    local = [
        r.model_copy(update={"status": "reserved"})
        if r.id in excluded and r.status == "idle"
        else r
        for r in latest.robots()
    ]
    return CoalitionProblem.build(filter_robots(local + others, task), task)


def same(a: CoalitionProblem, b: CoalitionProblem) -> None:
    assert a.ids == b.ids
    assert a.capabilities == b.capabilities
    # Bit for bit: the same floats, not close ones.
    assert a.time.tobytes() == b.time.tobytes()
    assert a.cost.tobytes() == b.cost.tobytes()
    assert np.array_equal(a.uses, b.uses) and a.uses.shape == b.uses.shape
    assert np.array_equal(a.need, b.need)
    assert (a.max_robots, a.max_cost, a.max_time) == (b.max_robots, b.max_cost, b.max_time)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(fleets())
def test_the_columns_filter_and_terms_equal_the_robot_path(
    fleet: tuple[LatestStates, list[str], list[Robot], Task],
) -> None:
    latest, excluded, others, task = fleet
    found = candidates(latest.columns(), task, excluded, others)
    same(found.problem, expected(latest, excluded, others, task))
    assert found.clouds == tuple(
        "cloud-b" if rid.startswith("b-") else "cloud-a" for rid in found.problem.ids
    )


def test_forgotten_robots_leave_the_columns() -> None:
    clock = Clock()
    latest = LatestStates("cloud-a", OFFLINE_AFTER, clock, forget_after=60.0)
    fields = {
        "cloud": "cloud-a",
        "position": [1.0, 2.0],
        "speed": 1.0,
        "battery": 90.0,
        "status": "idle",
        "travel_cost_per_m": 0.1,
        "capabilities": {"light": {"kind": "sensing", "time": 1.0, "cost": 1.0}},
    }
    for rid in ("a-2", "a-0", "a-1"):
        latest.accept(state({**fields, "id": rid}, 1))
    task = Task(
        location=[0.0, 0.0], sensing={"light": 1}, max_robots=1, max_cost=1e6, max_time=1e6,
        min_battery=20.0,
    )  # fmt: skip
    assert candidates(latest.columns(), task).problem.ids == ("a-0", "a-1", "a-2")
    clock.now += 30.0
    latest.accept(state({**fields, "id": "a-1"}, 2))
    clock.now += 40.0  # a-0 and a-2 silent for 70 s: forgotten at the next state
    latest.accept(state({**fields, "id": "a-1", "battery": 10.0}, 3))
    assert len(latest.columns()) == 1
    assert candidates(latest.columns(), task).problem.ids == ()
    latest.accept(state({**fields, "id": "a-3"}, 1))
    same(candidates(latest.columns(), task).problem, expected(latest, [], [], task))


def test_capability_sets_no_robot_has_are_dropped() -> None:
    latest = LatestStates("cloud-a", OFFLINE_AFTER, Clock())
    fields = {
        "id": "a-0",
        "cloud": "cloud-a",
        "position": [1.0, 2.0],
        "speed": 1.0,
        "battery": 90.0,
        "status": "idle",
        "travel_cost_per_m": 0.1,
    }
    # One robot whose capability's cost changes with every state: a new set each time.
    for seq in range(1, 1100):
        capability = {"light": {"kind": "sensing", "time": 1.0, "cost": float(seq)}}
        latest.accept(state({**fields, "capabilities": capability}, seq))
    columns = latest.columns()
    assert columns.set_count <= 1026, "the sets are started again past 2 per robot + 1024"
    task = Task(location=[0.0, 0.0], sensing={"light": 1}, max_robots=1, max_cost=1e6, max_time=1e6)
    same(candidates(columns, task).problem, expected(latest, [], [], task))
    assert candidates(columns, task).problem.cost[0] == 1099.0 + np.hypot(1.0, 2.0) * 0.1
