"""One brick as a robot, without I/O: the bricks file, the battery curves, odometry, a task."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest

from robocloud.errors import InvalidInput
from robocloud.fleet.messages import Assign
from robocloud.gateways.nxt import battery
from robocloud.gateways.nxt.brick import FAULT_HOLD, SILENT_AFTER, STALL_AFTER, Brick
from robocloud.gateways.nxt.bricks import parse_bricks
from robocloud.gateways.nxt.odometry import Odometry
from robocloud.gateways.nxt.telegrams import RUN_IDLE, RUN_RUNNING, OutputState

EXAMPLE = Path(__file__).parents[2] / "examples" / "nxt" / "thesis-bricks.json"
B, C, A = 1, 2, 0


def example() -> dict[str, Any]:
    data: dict[str, Any] = json.loads(EXAMPLE.read_text())
    return data


# -- the bricks file ---------------------------------------------------------------------


def test_the_thesis_example_is_a_valid_bricks_file() -> None:
    bricks = parse_bricks(example(), "thesis-bricks.json")
    assert sorted(bricks.robots) == ["nxt-base-1", "nxt-base-2", "nxt-tribot"]
    assert set(bricks.robots["nxt-tribot"].offered()) == {"grabber"}
    assert set(bricks.robots["nxt-base-1"].offered()) == {"light", "kicker"}


def _broken(change: Any) -> str:
    data = example()
    change(data)
    with pytest.raises(InvalidInput) as caught:
        parse_bricks(data, "f.json")
    return caught.value.message


def test_faults_in_the_bricks_file_are_sentences_naming_the_field() -> None:
    tribot = "robots.nxt-tribot"

    def no_reach(d: Any) -> None:
        del d["robots"]["nxt-tribot"]["reach"]

    assert _broken(no_reach) == f"f.json: {tribot}.reach is missing."

    def both(d: Any) -> None:
        d["robots"]["nxt-tribot"]["reach"] = {"tcp": "h:1", "bluetooth": "00:16:53:0A:1B:2C"}

    assert "give exactly one of bluetooth and tcp" in _broken(both)

    def bad_address(d: Any) -> None:
        d["robots"]["nxt-tribot"]["reach"] = {"bluetooth": "00:16:53"}

    assert f"{tribot}.reach.bluetooth" in _broken(bad_address)

    def same_port(d: Any) -> None:
        d["robots"]["nxt-tribot"]["build"]["arm"]["port"] = "B"

    assert "different ports" in _broken(same_port)

    def wheel(d: Any) -> None:
        d["robots"]["nxt-tribot"]["build"]["wheel_diameter"] = 0

    assert f"{tribot}.build.wheel_diameter: input should be greater than 0" in _broken(wheel)

    def sensor(d: Any) -> None:
        d["robots"]["nxt-tribot"]["sensors"]["5"] = "light"

    assert f"{tribot}.sensors.5" in _broken(sensor)

    def search_without_light(d: Any) -> None:
        d["robots"]["nxt-base-1"]["sensors"]["3"] = "touch"

    assert "sensor port 3, which sensors does not list as a light sensor" in _broken(
        search_without_light
    )

    def two_things(d: Any) -> None:
        d["robots"]["nxt-tribot"]["capabilities"]["grabber"]["steps"] = [{"arm": "open", "wait": 1}]

    assert "exactly one of arm, motor, search and wait" in _broken(two_things)

    def same_brick(d: Any) -> None:
        d["robots"]["nxt-base-2"]["reach"] = d["robots"]["nxt-base-1"]["reach"]

    assert "two robots are the same brick (tcp 127.0.0.1:7102)" in _broken(same_brick)

    def bad_id(d: Any) -> None:
        d["robots"]["a/b"] = d["robots"].pop("nxt-tribot")

    assert "f.json: robots:" in _broken(bad_id)


# -- the battery and the pose -------------------------------------------------------------


@pytest.mark.parametrize(
    ("millivolts", "kind", "percent"),
    [
        (9000, "aa", 100.0),
        (9400, "aa", 100.0),
        (7750, "aa", 50.0),
        (6500, "aa", 0.0),
        (6000, "aa", 0.0),
        (8200, "rechargeable", 100.0),
        (7600, "rechargeable", 50.0),
        (7000, "rechargeable", 0.0),
    ],
)
def test_the_battery_curves(millivolts: int, kind: str, percent: float) -> None:
    assert battery.percent(millivolts, kind) == percent  # type: ignore[arg-type]


def test_odometry_of_a_straight_line_and_a_turn_in_place() -> None:
    odo = Odometry(0.0, 0.0, 0.0, wheel_diameter=0.056, track_width=0.112)
    odo.advance(360, 360)  # one turn of each wheel: the circumference, 0.17593 m
    assert (odo.x, odo.y, odo.heading) == pytest.approx((math.pi * 0.056, 0.0, 0.0))
    quarter = odo.turn_degrees(math.pi / 2)  # each wheel 0.056 * pi/2 m: 180 degrees
    assert quarter == pytest.approx(180.0)
    odo.advance(-quarter, quarter)
    assert (odo.x, odo.y, odo.heading) == pytest.approx((math.pi * 0.056, 0.0, math.pi / 2))
    odo.advance(360, 360)
    assert (odo.x, odo.y) == pytest.approx((math.pi * 0.056, math.pi * 0.056))


# -- a task's life -------------------------------------------------------------------------


def out(port: int, rotation: int, run: int = RUN_RUNNING, power: int = 75) -> OutputState:
    return OutputState(port, power, 7, 1, 0, run, 0, 0, 0, rotation)


class Bench:
    """A Brick fed by hand, as the driver would."""

    def __init__(self, robot: str = "nxt-base-1") -> None:
        config = parse_bricks(example(), "x").robots[robot]
        self.brick = Brick(robot, config, 10.0)
        self.now = 0.0
        self.counts = {A: 0, B: 0, C: 0}
        self.brick.on_connected(self.now)
        self.brick.on_battery(8600)
        self.read()
        self.brick.stopped()

    def read(self, run: int = RUN_RUNNING) -> None:
        self.brick.on_outputs({p: out(p, c, run) for p, c in self.counts.items()}, self.now)

    def start(self) -> dict[int, tuple[int, int]]:
        movement = self.brick.next_movement(self.now)
        assert movement is not None
        self.brick.started(movement, self.now)
        return movement.motors

    def finish(self, motors: dict[int, tuple[int, int]]) -> None:
        for port, (power, limit) in motors.items():
            self.counts[port] += limit if power > 0 else -limit
        self.now += 0.5
        self.read(RUN_IDLE)


def test_a_task_drives_to_the_location_searches_and_ends_done() -> None:
    bench = Bench()
    brick = bench.brick
    assert brick.state("c", 0.0, 1.0) is not None
    assert (
        brick.refuse(Assign(request_id="r1", location=[9.0, 10.0], capabilities=["light"]), 0.0)
        is None
    )
    brick.take(Assign(request_id="r1", location=[9.0, 10.0], capabilities=["light"]))
    drive = bench.start()  # facing +x already: no turn, straight 1 m
    limit = round(1.0 / (math.pi * 0.056) * 360)
    assert drive == {B: (75, limit), C: (75, limit)}
    bench.now += 0.5
    bench.counts[B] += limit // 2
    bench.counts[C] += limit // 2
    bench.read()
    state = brick.state("c", bench.now, 1.0)
    assert state is not None and state.task is not None
    assert state.task.phase == "travel" and 0.2 < state.task.progress < 0.5
    assert state.position[0] == pytest.approx(8.5, abs=0.01)
    bench.counts[B] += limit - limit // 2
    bench.counts[C] += limit - limit // 2
    bench.now += 0.5
    bench.read(RUN_IDLE)
    search = bench.start()
    assert set(search) == {B, C}
    assert brick.sensor_to_read() == 2
    bench.now += 0.2
    brick.on_sensor(2, 35, bench.now)  # the floor
    assert brick.job is not None and brick.job.phase == "work"
    brick.on_sensor(2, 62, bench.now)  # red: the search ends, the motors brake
    assert brick.stop_wanted
    brick.stopped()
    assert brick.next_movement(bench.now) is None
    state = brick.state("c", bench.now, 2.0)
    assert state is not None and state.status == "idle"
    assert state.task is not None and state.task.phase == "done" and state.task.progress == 1.0
    assert state.last_task == state.task


def test_a_motor_that_does_not_turn_fails_the_task_with_the_reason() -> None:
    bench = Bench()
    brick = bench.brick
    brick.take(Assign(request_id="r2", location=[10.0, 10.0], capabilities=["kicker"]))
    bench.start()
    bench.now += STALL_AFTER / 2
    bench.read()  # counts did not move, but not for long yet
    assert brick.job is not None
    bench.now += STALL_AFTER
    bench.read()
    assert brick.job is None and brick.stop_wanted
    state = brick.state("c", bench.now, 1.0)
    assert state is not None and state.status == "offline"
    assert state.task is not None and state.task.phase == "failed"
    assert state.task.reason == (
        "motor B stalled: it did not turn for 1 s at power 75 while driving to the location."
    )
    later = brick.state("c", bench.now + FAULT_HOLD + 0.1, 1.0)
    assert later is not None and later.status == "idle"


def test_an_arm_that_stops_part_way_when_closing_holds_something() -> None:
    bench = Bench("nxt-tribot")
    brick = bench.brick
    brick.take(Assign(request_id="r3", location=[10.0, 12.0], capabilities=["grabber"]))
    close = bench.start()  # at the location already; the arm is open: "open" is no move
    assert close == {A: (40, 100)}
    bench.counts[A] += 60
    bench.now += 0.3
    bench.read()
    bench.now += STALL_AFTER + 0.1
    bench.read()  # stands at 60 of 100 degrees: holding the ball
    assert brick.stop_wanted
    brick.stopped()
    assert brick.next_movement(bench.now) is None
    assert brick.finished is not None and brick.finished.phase == "done"


def test_a_silent_brick_is_offline_and_its_task_failed() -> None:
    bench = Bench()
    brick = bench.brick
    brick.take(Assign(request_id="r4", location=[12.0, 10.0], capabilities=["light"]))
    bench.start()
    brick.on_silence(bench.now + SILENT_AFTER / 2)
    assert brick.job is not None
    brick.on_silence(bench.now + SILENT_AFTER + 0.1)
    assert brick.job is None and brick.status(bench.now + 3) == "offline"
    assert brick.finished is not None and brick.finished.reason is not None
    assert brick.finished.reason.startswith("the brick stopped answering (silent for 2.1 s)")


def test_commands_refused_and_cancelled_as_the_protocol_says() -> None:
    bench = Bench()
    brick = bench.brick
    light = Assign(request_id="r5", location=[12.0, 10.0], capabilities=["light"])
    assert (
        brick.refuse(Assign(request_id="x", location=[0.0, 0.0], capabilities=["grabber"]), 0.0)
        == "robot nxt-base-1 lacks the capability grabber."
    )
    brick.take(light)
    assert brick.refuse(light, 0.0) is None  # the same request again
    other = Assign(request_id="r6", location=[0.0, 0.0], capabilities=["light"])
    assert brick.refuse(other, 0.0) == "robot nxt-base-1 is busy with request r5."
    assert brick.cancel("r6") == "robot nxt-base-1 is not on request r6 but on request r5."
    assert brick.cancel("r5") is None and brick.stop_wanted and brick.job is None
    assert brick.cancel("r5") is None  # twice is harmless
    low = Bench()
    low.brick.on_battery(6700)
    assert low.brick.refuse(light, 0.0) == (
        "robot nxt-base-1's battery (8.0%) is below the 10% a task needs."
    )


def test_a_task_away_from_the_heading_turns_first() -> None:
    bench = Bench()
    brick = bench.brick
    brick.take(Assign(request_id="r7", location=[8.0, 11.0], capabilities=["light"]))
    turn = bench.start()  # +90 degrees: the right wheel ahead, the left back
    degrees = round(0.112 / 2 * math.pi / 2 / (math.pi * 0.056) * 360)
    assert turn == {B: (-75, degrees), C: (75, degrees)}
    bench.finish(turn)
    assert brick.odometry.heading == pytest.approx(math.pi / 2, abs=0.01)
    drive = bench.start()
    bench.finish(drive)
    assert (brick.odometry.x, brick.odometry.y) == pytest.approx((8.0, 11.0), abs=0.005)


def test_a_far_location_is_driven_in_legs_a_tacho_limit_can_hold() -> None:
    bench = Bench()
    brick = bench.brick
    brick.take(Assign(request_id="far", location=[2508.0, 10.0], capabilities=["light"]))
    legs = []
    while True:
        motors = bench.start()
        if brick.movement is not None and brick.movement.search is not None:
            break  # at the location: the light capability's search
        legs.append(motors[B][1])
        bench.finish(motors)
    assert len(legs) == 3 and max(legs) < 2**32
    assert brick.odometry.x == pytest.approx(2508.0, abs=0.01)


def test_a_link_back_within_the_silence_limit_restarts_the_movement_not_the_task() -> None:
    bench = Bench()
    brick = bench.brick
    brick.take(Assign(request_id="r8", location=[10.0, 10.0], capabilities=["light"]))
    drive = bench.start()
    bench.counts[B] += drive[B][1] // 2  # half way when the link drops
    bench.counts[C] += drive[C][1] // 2
    bench.now += 0.5
    bench.read()
    brick.on_silence(bench.now + SILENT_AFTER / 2)  # back before it counts as offline
    brick.on_connected(bench.now + 1.0)
    assert brick.stop_wanted and brick.job is not None
    brick.stopped()
    bench.now += 1.0
    bench.read()  # the new connection's first counts: where the brick stands
    again = bench.start()  # no turn needed: straight on, the rest of the way
    assert again[B][1] == pytest.approx(drive[B][1] / 2, abs=2)
    bench.now += STALL_AFTER + 0.5
    bench.finish(again)
    assert brick.job is not None and brick.job.phase == "travel"
    assert brick.position() == pytest.approx((10.0, 10.0), abs=0.01)


def test_what_a_motor_coasts_past_its_limit_is_learned_and_taken_off_the_next() -> None:
    bench = Bench()
    brick = bench.brick
    brick.take(Assign(request_id="r9", location=[8.0, 10.0], capabilities=["kicker"]))
    close = bench.start()
    assert close == {A: (60, 120)}
    bench.counts[A] += 128  # 8 degrees past the limit before it came to rest
    bench.now += 0.5
    bench.read(RUN_IDLE)
    assert brick.coast == {60: 8.0}
    opening = bench.start()  # back from 128 to 0: 128 degrees, less the 8 it will coast
    assert opening == {A: (-60, 120)}
