"""One simulated robot's kinematics, battery and task states, without Zenoh."""

import math

import pytest

from robocloud.fleet.messages import Assign
from robocloud.sim.robot import FINISHED_LINGER, Background, SimRobot


def make(**changes: object) -> SimRobot:
    fields: dict[str, object] = {
        "id": "a-0001",
        "cloud": "cloud-a",
        "position": [0.0, 0.0],
        "speed": 2.0,
        "battery": 80.0,
        "status": "idle",
        "travel_cost_per_m": 0.05,
        "capabilities": {
            "light": {"kind": "sensing", "time": 20.0, "cost": 1.0},
            "grabber": {"kind": "actuating", "time": 60.0, "cost": 8.0},
        },
    }
    fields.update(changes)
    return SimRobot.from_json(fields)


def go(
    x: float = 60.0, y: float = 80.0, execution: str = "parallel", request_id: str = "r-1"
) -> Assign:
    return Assign.model_validate(
        {
            "request_id": request_id,
            "location": [x, y],
            "capabilities": ["light", "grabber"],
            "execution": execution,
        }
    )


def test_kind_follows_the_actuator() -> None:
    assert make().kind == "tribot"
    kicker = {"kicker": {"kind": "actuating", "time": 60.0, "cost": 8.0}}
    assert make(capabilities=kicker).kind == "base"
    assert make(kind="rover").kind == "rover"


def test_a_task_drives_straight_then_works_then_is_done() -> None:
    robot = make()
    assert robot.assign(go()).ok
    assert robot.status == "busy" and robot.dirty
    start = robot.state(0.0)
    assert start.task is not None and (start.task.phase, start.task.progress) == ("travel", 0.0)

    # 100 m at 2 m/s = 50 s, then 60 s of work (parallel: the longest time).
    assert robot.advance(25.0, 1.0) == []
    assert robot.position == pytest.approx((30.0, 40.0))
    assert robot.battery == pytest.approx(80.0 - 0.5)
    assert robot.state(1.0).task.progress == pytest.approx(25.0 / 110.0)  # type: ignore[union-attr]

    arrived = robot.advance(35.0, 2.0)  # 25 s of driving, 10 s of work
    assert [s.task.phase for s in arrived] == ["work"]  # type: ignore[union-attr]
    assert robot.position == (60.0, 80.0)
    assert robot.state(2.0).task.progress == pytest.approx(60.0 / 110.0)  # type: ignore[union-attr]

    done = robot.advance(100.0, 3.0)
    assert len(done) == 1 and done[0].status == "idle"
    assert done[0].task is not None and (done[0].task.phase, done[0].task.progress) == ("done", 1.0)
    assert robot.battery == pytest.approx(80.0 - 1.0 - 60.0 * 0.02)
    assert robot.state(3.0 + FINISHED_LINGER - 0.1).task is not None
    assert robot.state(3.0 + FINISHED_LINGER).task is None
    seqs = [robot.state(4.0).seq, robot.state(4.0).seq]
    assert seqs[1] == seqs[0] + 1


def test_one_long_step_reports_every_phase_in_order() -> None:
    robot = make()
    robot.assign(go(execution="sequential"))  # 50 s + 80 s
    changes = robot.advance(1000.0, 5.0)
    assert [(s.status, s.task.phase) for s in changes] == [  # type: ignore[union-attr]
        ("busy", "work"),
        ("idle", "done"),
    ]
    assert robot.battery == pytest.approx(80.0 - 1.0 - 80.0 * 0.02)


def test_a_task_at_the_robot_with_no_work_is_done_at_once() -> None:
    robot = make(capabilities={"light": {"kind": "sensing", "time": 0.0, "cost": 1.0}})
    assert robot.assign(Assign(request_id="r", location=[0.0, 0.0], capabilities=["light"])).ok
    assert [s.task.phase for s in robot.advance(0.1, 1.0)] == ["done"]  # type: ignore[union-attr]


def test_refusals_repeats_and_cancel() -> None:
    robot = make()
    assert robot.assign(go()).ok
    assert robot.assign(go()).ok  # the same request again
    other = robot.assign(go(request_id="r-2"))
    assert not other.ok and other.error == "robot a-0001 is busy with request r-1."
    wrong = robot.cancel("r-2")
    assert not wrong.ok and robot.job is not None
    robot.advance(10.0, 1.0)
    assert robot.cancel("r-1").ok
    assert robot.status == "idle" and robot.job is None
    assert robot.position == pytest.approx((12.0, 16.0))  # stopped where it was
    assert robot.state(1.0).task is None
    assert robot.cancel("r-1").ok  # nothing to stop

    weak = make(battery=2.0)
    assert "too low" in str(weak.assign(go()).error)
    charging = make(status="charging")
    assert charging.assign(go()).error == "robot a-0001 is charging, not idle."


def test_the_battery_runs_out_mid_task() -> None:
    robot = make(battery=3.0)  # enough for 100 m (1%) and 60 s (1.2%)
    robot.assign(go())
    robot.battery = 0.5  # drained by something else: 50 m left in it
    changes = robot.advance(100.0, 1.0)
    assert len(changes) == 1
    assert changes[0].status == "offline" and changes[0].battery == 0.0
    assert changes[0].task is not None and changes[0].task.phase == "failed"
    assert robot.position == pytest.approx((30.0, 40.0))
    assert robot.dead and robot.advance(10.0, 2.0) == []


def test_a_battery_fault_fails_the_task_now() -> None:
    robot = make()
    robot.assign(go())
    robot.advance(10.0, 1.0)
    robot.kill_battery(1.0)
    state = robot.state(1.0)
    assert (state.status, state.battery) == ("offline", 0.0)
    assert state.task is not None and state.task.phase == "failed"
    assert state.task.progress == pytest.approx(10.0 / 110.0)
    assert robot.assign(go(request_id="r-2")).error == "robot a-0001 is offline, not idle."


def test_a_background_activity_ends_on_its_own() -> None:
    robot = make(battery=50.0)
    robot.start_background(Background("charging", 100.0, 0.1))
    assert robot.status == "charging"
    assert robot.advance(60.0, 1.0) == []
    assert robot.battery == pytest.approx(56.0)
    ended = robot.advance(60.0, 2.0)
    assert [s.status for s in ended] == ["idle"] and robot.battery == pytest.approx(60.0)
    robot.start_background(Background("offline", math.inf))
    assert robot.advance(1e9, 3.0) == []
    assert robot.state(3.0).status == "offline"


def held(request_id: str = "r-1") -> Assign:
    return go(request_id=request_id).model_copy(update={"hold": True})


def test_a_held_task_waits_at_the_place_until_its_start() -> None:
    robot = make()
    assert robot.state(0.0).protocol == "1.2"
    assert robot.assign(held()).ok
    changes = robot.advance(50.0, 1.0)  # 100 m at 2 m/s: there
    assert [c.task.phase for c in changes if c.task] == ["waiting"]
    assert robot.advance(500.0, 2.0) == []  # waits as long as it takes, no progress
    waiting = robot.state(2.0)
    assert waiting.status == "busy" and waiting.task is not None
    assert (waiting.task.phase, waiting.task.progress) == ("waiting", pytest.approx(50 / 110))
    assert not robot.start("r-2").ok  # another request's start
    assert robot.start("r-1").ok and robot.dirty
    assert robot.state(3.0).task.phase == "work"  # type: ignore[union-attr]
    done = robot.advance(60.0, 4.0)
    assert [c.task.phase for c in done if c.task] == ["done"]


def test_a_start_before_arrival_makes_it_work_on_arrival() -> None:
    robot = make()
    assert not robot.start("r-1").ok  # no task yet
    assert robot.assign(held()).ok
    assert robot.start("r-1").ok
    phases = [c.task.phase for c in robot.advance(110.0, 1.0) if c.task]
    assert phases == ["work", "done"]
