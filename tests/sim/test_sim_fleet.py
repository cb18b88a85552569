"""The fleet simulator and the robot link together, over a real loopback Zenoh network."""

import json
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import pytest
import zenoh

from loopback_ports import free_endpoint
from robocloud.errors import InvalidInput
from robocloud.fleet import (
    Ack,
    Assign,
    State,
    ZenohRobotLink,
    keys,
    open_client,
    open_router,
    wait_for_liveliness,
)
from robocloud.sim.fleet import FleetSimulator
from waiting import wait_until

CLOUD = "cloud-t"
ROBOTS = 30
SPEEDUP = 100.0


def robot_json(i: int) -> dict[str, Any]:
    return {
        "id": f"t-{i:04d}",
        "cloud": CLOUD,
        "position": [100.0 * i, 500.0],
        "speed": 2.0,
        "battery": 90.0,
        "status": "idle",
        "travel_cost_per_m": 0.05,
        "capabilities": {
            "light": {"kind": "sensing", "time": 20.0, "cost": 1.0},
            "grabber": {"kind": "actuating", "time": 60.0, "cost": 8.0},
        },
    }


@dataclass
class Setup:
    router: zenoh.Session
    sim: FleetSimulator
    link: ZenohRobotLink
    heard: dict[str, list[State]]


@pytest.fixture(scope="module")
def setup() -> Iterator[Setup]:
    endpoint = free_endpoint()
    router = open_router([endpoint])
    client = open_client([endpoint])
    # Robots publish every 0.9 s; 2.5 s of silence leaves room for a loaded machine.
    link = ZenohRobotLink(router, CLOUD, offline_after=2.5, command_timeout=1.0)
    heard: dict[str, list[State]] = {}
    lock = threading.Lock()

    def record(state: State) -> None:
        with lock:
            heard.setdefault(state.id, []).append(state)

    link.on_state(record)
    robots = [robot_json(i) for i in range(1, ROBOTS + 1)]
    with FleetSimulator(CLOUD, robots, client, speedup=SPEEDUP) as sim:
        assert wait_for_liveliness(router, keys.all_sim_tokens(CLOUD), 3.0)
        assert wait_until(lambda: len(link.states()) == ROBOTS, timeout=3.0)
        yield Setup(router, sim, link, heard)
    link.close()
    client.close()  # type: ignore[no-untyped-call]
    router.close()  # type: ignore[no-untyped-call]


def latest(setup: Setup, robot_id: str) -> State:
    return setup.link.states()[robot_id]


def go(setup: Setup, robot_id: str, dx: float, dy: float, request_id: str) -> Assign:
    x, y = latest(setup, robot_id).position
    return Assign(
        request_id=request_id, location=[x + dx, y + dy], capabilities=["light", "grabber"]
    )


def control(setup: Setup, payload: bytes) -> Ack:
    replies = list(setup.router.get(keys.sim_control(CLOUD), payload=payload, timeout=2.0))
    assert len(replies) == 1 and replies[0].ok is not None
    return Ack.model_validate_json(replies[0].ok.payload.to_bytes())


def test_the_link_sees_every_robot(setup: Setup) -> None:
    robots = setup.link.robots()
    assert [r.id for r in robots] == [f"t-{i:04d}" for i in range(1, ROBOTS + 1)]
    assert {r.status for r in robots} == {"idle"}
    assert {s.kind for s in setup.link.states().values()} == {"tribot"}
    assert max(setup.link.ages().values()) < 2.0  # everyone publishes every second


def test_an_assigned_robot_travels_works_and_ends_idle_at_the_location(setup: Setup) -> None:
    command = go(setup, "t-0001", 60.0, 80.0, "r-life")  # 50 s of driving, 60 s of work
    ack = setup.link.assign("t-0001", command)
    assert ack == Ack(ok=True, robot="t-0001", request_id="r-life")

    def finished() -> bool:
        task = latest(setup, "t-0001").task
        return task is not None and task.phase == "done"

    assert wait_until(finished, timeout=5.0)
    end = latest(setup, "t-0001")
    assert end.status == "idle" and end.position == command.location
    assert end.battery == pytest.approx(90.0 - 1.0 - 60.0 * 0.02)
    mine = [s for s in setup.heard["t-0001"] if s.task and s.task.request_id == "r-life"]
    phases = [s.task.phase for s in mine if s.task]
    first = {phase: phases.index(phase) for phase in ("travel", "work", "done")}
    assert first["travel"] < first["work"] < first["done"]
    assert all(s.status == "busy" for s in mine if s.task and s.task.phase != "done")
    progress = [s.task.progress for s in mine if s.task]
    assert progress == sorted(progress) and progress[-1] == 1.0


def test_a_busy_robot_refuses_and_a_cancel_stops_it(setup: Setup) -> None:
    far = go(setup, "t-0002", 0.0, 1000.0, "r-far")  # 500 s of driving
    assert setup.link.assign("t-0002", far).ok
    assert setup.link.assign("t-0002", far).ok  # repeated: still ok
    other = setup.link.assign("t-0002", go(setup, "t-0002", 0.0, 10.0, "r-other"))
    assert not other.ok and other.error == "robot t-0002 is busy with request r-far."
    assert wait_until(lambda: latest(setup, "t-0002").position[1] > 520.0)

    assert setup.link.cancel("t-0002", "r-far").ok
    assert wait_until(lambda: latest(setup, "t-0002").status == "idle")
    stopped = latest(setup, "t-0002")
    assert stopped.task is None and 500.0 < stopped.position[1] < 1500.0
    assert setup.link.cancel("t-0002", "r-far").ok


def test_a_silent_robot_goes_offline_and_does_not_answer(setup: Setup) -> None:
    ack = control(setup, json.dumps({"fault": "silent", "robot": "t-0003"}).encode())
    assert ack.ok and ack.robot == "t-0003"
    assert wait_until(
        lambda: {r.id: r.status for r in setup.link.robots()}["t-0003"] == "offline", timeout=5.0
    )
    heard_from_t4 = len(setup.heard["t-0004"])
    assert wait_until(lambda: len(setup.heard["t-0004"]) > heard_from_t4, timeout=3.0)  # speaks on
    assert {r.id: r.status for r in setup.link.robots()}["t-0004"] == "idle"
    lost = setup.link.assign("t-0003", go(setup, "t-0003", 1.0, 1.0, "r-lost"))
    assert lost.unanswered

    assert control(setup, b'{"fault": "recover", "robot": "t-0003"}').ok
    assert wait_until(
        lambda: {r.id: r.status for r in setup.link.robots()}["t-0003"] == "idle", timeout=2.0
    )


def test_a_battery_fault_mid_task_fails_it(setup: Setup) -> None:
    assert setup.link.assign("t-0005", go(setup, "t-0005", 0.0, 1000.0, "r-doomed")).ok
    assert wait_until(lambda: latest(setup, "t-0005").status == "busy")
    assert setup.sim.inject("battery", "t-0005").ok

    def failed() -> bool:
        state = latest(setup, "t-0005")
        return state.status == "offline" and state.task is not None and state.task.phase == "failed"

    assert wait_until(failed, timeout=2.0)
    assert latest(setup, "t-0005").battery == 0.0
    again = setup.link.assign("t-0005", go(setup, "t-0005", 1.0, 1.0, "r-next"))
    assert again.error == "robot t-0005 is offline, not idle."


def test_bad_messages_get_sentences_and_strangers_get_nothing(setup: Setup) -> None:
    replies = list(
        setup.router.get(keys.cmd_key(CLOUD, "t-0006"), payload=b'{"type": "jump"}', timeout=2.0)
    )
    ack = Ack.model_validate_json(replies[0].ok.payload.to_bytes())  # type: ignore[union-attr]
    assert not ack.ok and ack.robot == "t-0006" and ack.error and ack.error.endswith(".")
    assert "command" in ack.error

    stranger = setup.link.assign("t-0999", go(setup, "t-0006", 1.0, 1.0, "r-x"))
    assert stranger.unanswered
    assert control(setup, b'{"fault": "battery", "robot": "t-0999"}').error == (
        f"there is no robot t-0999 in {CLOUD}."
    )
    assert not control(setup, b'{"fault": "fire", "robot": "t-0006"}').ok


def test_the_simulator_refuses_a_bad_fleet() -> None:
    with pytest.raises(InvalidInput, match="robot t-0001 belongs to cloud-t, not cloud-u"):
        FleetSimulator("cloud-u", [robot_json(1)], session=None)  # type: ignore[arg-type]
    with pytest.raises(InvalidInput, match="used twice"):
        FleetSimulator(CLOUD, [robot_json(1), robot_json(1)], session=None)  # type: ignore[arg-type]
    with pytest.raises(InvalidInput, match=r"robots\[0\]\.speed"):
        FleetSimulator(CLOUD, [{**robot_json(1), "speed": 0}], session=None)  # type: ignore[arg-type]
    with pytest.raises(InvalidInput, match="speedup"):
        FleetSimulator(CLOUD, [], session=None, speedup=0)  # type: ignore[arg-type]
