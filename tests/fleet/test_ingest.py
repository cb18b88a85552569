"""The fast state reader: pydantic's verdicts and sentences, msgspec's speed; the robots kept."""

from __future__ import annotations

import json
from typing import Any

import pydantic
import pytest

from robocloud.errors import describe_validation_errors
from robocloud.fleet.ingest import Refusal, StateReader, encode_batch
from robocloud.fleet.link import LatestStates
from robocloud.fleet.messages import State
from robocloud.sim.robot import SimRobot
from robocloud.sim.roster import cloud_robots

TASK = {"request_id": "r-1", "phase": "travel", "progress": 0.25, "capabilities": ["grabber"]}


def state(**changes: Any) -> dict[str, Any]:
    fields: dict[str, Any] = {
        "id": "a-0001",
        "cloud": "cloud-a",
        "kind": "tribot",
        "position": [120.0, 40.5],
        "speed": 1.5,
        "battery": 86.0,
        "status": "busy",
        "travel_cost_per_m": 0.05,
        "capabilities": {
            "grabber": {"kind": "actuating", "time": 90.0, "cost": 8.0},
            "light": {"kind": "sensing", "time": 10, "cost": 1},
        },
        "task": TASK,
        "last_task": None,
        "seq": 1042,
        "sent_at": 1767225600.25,
    }
    fields.update(changes)
    return fields


def pydantic_verdict(payload: bytes) -> State | Refusal:
    try:
        return State.model_validate_json(payload, strict=True)  # as the schemas read it
    except pydantic.ValidationError as error:
        described = describe_validation_errors(error.errors())
        return Refusal(None, described.field or "state", described.message)


BAD: list[dict[str, Any] | bytes] = [
    state(battery="90.5"),  # a lax form pydantic takes, the schemas refuse: refused
    {k: v for k, v in state().items() if k != "kind"},
    state(battery=150.0),
    state(battery=-1),
    state(speed=0.0),
    state(position=[1.0, 2.0, 3.0]),
    state(position=[1e8, 0.0]),
    state(status="asleep"),
    state(seq=-1),
    state(seq=1.5),
    state(id=""),
    state(id="a\x01b"),
    state(kind="x" * 129),
    state(travel_cost_per_m=2e9),
    state(capabilities={"grabber": {"kind": "actuating", "time": 1.0, "cost": 1.0, "x": 1}}),
    state(capabilities={"grabber": {"kind": "flying", "time": 1.0, "cost": 1.0}}),
    state(capabilities={"bad\nname": {"kind": "sensing", "time": 1.0, "cost": 1.0}}),
    state(task={**TASK, "progress": 1.5}),
    state(task={**TASK, "phase": "nap"}),
    state(last_task={**TASK, "request_id": ""}),
    b'{"id": "a-0001", "sent_at": 1e999}',
    json.dumps(state()).replace("1767225600.25", "1e999").encode(),
    b"[1, 2]",
    b"not json",
    b"",
]


@pytest.mark.parametrize("message", BAD)
def test_a_bad_state_is_refused_with_pydantics_sentence(message: dict[str, Any] | bytes) -> None:
    payload = message if isinstance(message, bytes) else json.dumps(message).encode()
    expected = pydantic_verdict(payload)
    assert isinstance(expected, Refusal)
    read = StateReader().read(payload)
    assert isinstance(read, Refusal)
    assert (read.field, read.sentence) == (expected.field, expected.sentence)


GOOD: list[dict[str, Any]] = [
    state(),
    state(task=None, status="idle"),
    state(last_task={**TASK, "phase": "done", "progress": 1.0}),
    state(last_task=TASK),
    state(extra_field={"anything": 1}),
    state(id="ü-robot ünïcode"),
    state(id="a\u00a0b"),  # a non-breaking space: not printable, but the pattern allows it
]


@pytest.mark.parametrize("message", GOOD)
def test_a_good_state_reads_as_pydantic_reads_it(message: dict[str, Any]) -> None:
    payload = json.dumps(message).encode()
    reader = StateReader()
    for _ in range(2):  # the second time from what the reader remembers
        read = reader.read(payload)
        assert isinstance(read, State)
        assert read == State.model_validate_json(payload)
        assert read.model_dump_json() == State.model_validate_json(payload).model_dump_json()
        assert read.to_robot() == State.model_validate_json(payload).to_robot()


def test_a_batch_keeps_the_good_states_and_names_the_robots_of_the_bad() -> None:
    reader = StateReader()
    batch = [state(id="a-1"), state(id="a-2", battery=101.0), state(id="a-3"), {"cloud": 1}]
    states, refusals = reader.read_batch(json.dumps(batch).encode())
    assert [s.id for s in states] == ["a-1", "a-3"]
    assert [(r.robot, r.field) for r in refusals] == [("a-2", "battery"), (None, "id")]
    big = state(id="a-4", kind="k" * 100)
    states, refusals = reader.read_batch(json.dumps([big]).encode(), max_state_bytes=100)
    assert states == [] and refusals[0].robot == "a-4" and "at most 100" in refusals[0].sentence
    assert reader.read_batch(b'{"id": "a-1"}')[1][0].field == "states"


def test_a_gateways_wire_states_read_back_as_the_robots_states(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    robots = [SimRobot.from_json(r) for r in cloud_robots("cloud-a", 5, seed=1)]
    reader = StateReader()

    def slow(payload: bytes) -> State | Refusal:
        raise AssertionError(f"a plain state went to pydantic: {payload!r}")

    monkeypatch.setattr(reader, "_slow", slow)  # every one of them on the fast path
    wire = [robot.wire_state(2000.0) for robot in robots]
    states, refusals = reader.read_batch(encode_batch(list(wire)))
    assert refusals == []
    for robot, read in zip(robots, states, strict=True):
        robot.seq -= 1  # the same message again, from the pydantic side
        assert read == robot.state(2000.0)


def test_latest_states_keep_a_robot_while_its_states_repeat_it() -> None:
    now = [0.0]
    latest = LatestStates("cloud-a", offline_after=5.0, clock=lambda: now[0])
    reader = StateReader()

    def accept(**changes: Any) -> None:
        read = reader.read(json.dumps(state(**changes)).encode())
        assert isinstance(read, State)
        latest.accept(read)

    accept(id="a-2", seq=1)
    accept(id="a-1", seq=1)
    first = latest.robots()
    assert [r.id for r in first] == ["a-1", "a-2"]
    accept(id="a-1", seq=2, sent_at=2e9)  # the same robot again: the same Robot
    assert latest.robots()[0] is first[0]
    accept(id="a-1", seq=3, sent_at=2e9 + 1, battery=50.0)  # changed: made again
    again = latest.robots()
    assert again[0] is not first[0] and again[0].battery == 50.0
    assert again[1] is first[1]
    listed = latest.robots()
    listed.clear()  # a copy: the next caller still gets every robot
    assert latest.robots() == again
    now[0] = 4.9
    assert {r.status for r in latest.robots()} == {"busy"}
    now[0] = 5.1  # silent too long: offline, without changing what is kept
    assert {r.status for r in latest.robots()} == {"offline"}
    assert latest.count() == 2
    accept(id="a-2", seq=9, sent_at=3e9)  # back: online again at once
    assert [r.status for r in latest.robots()] == ["offline", "busy"]
    now[0] = 9.0
    accept(id="a-1", seq=9, sent_at=3e9)
    assert [r.status for r in latest.robots()] == ["busy", "busy"]
    now[0] = 10.2  # a-2 last heard at 5.1: silent for over 5 s
    assert [r.status for r in latest.robots()] == ["busy", "offline"]
