"""The gateway against an in-process stand-in robot on its own loopback router; link checks."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import zenoh

from loopback_ports import free_port
from robocloud.fleet.messages import Assign, Cancel, State
from robocloud.gateways.ros2 import naming, standin
from robocloud.gateways.ros2 import standin_cdr as m
from robocloud.gateways.ros2.gateway import Ros2Gateway
from robocloud.gateways.ros2.link import RobotLink, ServiceClient
from robocloud.gateways.ros2.robots_file import parse_robots
from robocloud.gateways.zenoh_side import CommandHandler


@dataclass
class Side:
    """The cloud's side in memory: what the gateway publishes, and its command handler."""

    handler: CommandHandler
    cloud: str = "cloud-a"
    states: list[State] = field(default_factory=list)
    ids: set[str] = field(default_factory=set)
    changed: threading.Condition = field(default_factory=threading.Condition)

    def has(self, robot: str) -> bool:
        return robot in self.ids

    def add(self, robot: str) -> None:
        self.ids.add(robot)

    def remove(self, robot: str) -> None:
        self.ids.discard(robot)

    def publish(self, state: State) -> None:
        with self.changed:
            self.states.append(state)
            self.changed.notify_all()

    def close(self) -> None:
        pass

    def mark(self) -> int:
        with self.changed:
            return len(self.states)

    def wait(self, check: Any, timeout: float = 5.0, since: int = 0) -> State:
        """The newest state since the ``since``-th that passes ``check``, waiting for it."""
        with self.changed:
            found = self.changed.wait_for(
                lambda: next((s for s in reversed(self.states[since:]) if check(s)), None),
                timeout,
            )
        assert found is not None, f"no state as wanted in {timeout} s: {self.states[-3:]}"
        return found


@dataclass
class Rig:
    robot: standin.StandinRobot
    gateway: Ros2Gateway
    side: Side
    log: Path
    port: int

    def events(self) -> list[dict[str, Any]]:
        if not self.log.exists():
            return []
        return [json.loads(line) for line in self.log.read_text().splitlines()]

    def of(self, kind: str) -> list[dict[str, Any]]:
        return [e for e in self.events() if e["event"] == kind]


def wait_for(found: Any, what: str, timeout: float = 5.0) -> Any:
    """What ``found()`` returns once it is truthy (the robot's log is a file: it is looked at)."""
    deadline = time.monotonic() + timeout
    while not (value := found()):
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)
    return value


def rig(tmp_path: Path, *flags: str, distro: str = "jazzy") -> Iterator[Rig]:
    port = free_port()
    log = tmp_path / "robot.jsonl"
    args = standin.parse(["--listen", f"tcp/127.0.0.1:{port}", "--speed", "20", "--tf-hz", "10",
                          "--log", str(log), *flags])  # fmt: skip
    robot = standin.StandinRobot(args, args.listen, args.namespace, 0)
    stop = threading.Event()
    thread = threading.Thread(target=standin.run, args=([robot], args, stop), daemon=True)
    thread.start()
    robots = parse_robots({"robots": {"r": {
        "endpoint": f"tcp/127.0.0.1:{port}", "scheme": args.scheme, "distro": distro,
        "namespace": args.namespace, "speed": 20.0,
        "capabilities": {"cam": {"kind": "sensing", "time": 0.2, "cost": 1.0}}}}}, "f")  # fmt: skip
    sides: list[Side] = []
    gateway = Ros2Gateway(lambda h: sides.append(Side(h)) or sides[0], robots)
    gateway.start()
    try:
        yield Rig(robot, gateway, sides[0], log, port)
    finally:
        gateway.stop()
        stop.set()
        thread.join(5)
        robot.close()


@pytest.fixture
def old_robot(tmp_path: Path) -> Iterator[Rig]:
    yield from rig(tmp_path, "--old-attachment", "--namespace", "/bot7")


def test_a_robot_sending_the_older_attachment_joins_and_serves(old_robot: Rig) -> None:
    side = old_robot.side
    side.wait(lambda s: s.status == "idle")
    ack = side.handler("r", Assign(request_id="q1", location=[3.0, 0.0], capabilities=["cam"]))
    assert ack.ok, ack.error
    done = side.wait(lambda s: s.task is not None and s.task.phase == "done")
    assert done.last_task is not None and done.last_task.request_id == "q1"
    assert done.position == [pytest.approx(3.0), pytest.approx(0.0)]
    # Our requests were in the current form, checked strictly by the robot.
    assert not [e for e in old_robot.events() if e["event"] == "bad_request"]


def test_cancel_names_the_goal_alone_and_the_robot_is_idle_at_once(old_robot: Rig) -> None:
    side = old_robot.side
    side.wait(lambda s: s.status == "idle")
    assert side.handler(
        "r", Assign(request_id="q1", location=[500.0, 0.0], capabilities=["cam"])
    ).ok
    sent = wait_for(lambda: old_robot.of("send_goal"), "the goal")
    mark = side.mark()
    assert side.handler("r", Cancel(request_id="q1")).ok
    side.wait(lambda s: s.status == "idle" and s.task is None, timeout=1.0, since=mark)
    cancels = wait_for(lambda: old_robot.of("cancel_goal"), "cancel_goal")
    assert cancels[0]["goal_id"] == sent[-1]["goal_id"] and cancels[0]["stamp"] == [0, 0]
    assert cancels[0]["goal_id"] != "00" * 16


def test_the_robot_refuses_a_replayed_request_attachment(old_robot: Rig) -> None:
    """The stand-in's check is real: the same sequence number twice is not answered."""
    old_robot.side.wait(lambda s: s.status == "idle")
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{old_robot.port}"]))
    session = zenoh.open(config)
    try:
        key = old_robot.robot.key("get_result")
        client = ServiceClient()
        attachment = client.attachment()
        request = m.encode(m.GetResultRequest(m.uuid_of(bytes(16))))
        for _ in range(2):
            list(session.get(key, payload=request, attachment=attachment, timeout=1.0))
        bad = [e for e in old_robot.events() if e["event"] == "bad_request"]
        assert len(bad) == 1 and "sequence number 1 after 1" in bad[0]["problem"]
        list(session.get(key, payload=request, attachment=b"\x01" * 20, timeout=1.0))
        bad = [e for e in old_robot.events() if e["event"] == "bad_request"]
        assert "20 bytes, not 33" in bad[-1]["problem"]
    finally:
        session.close()  # type: ignore[no-untyped-call]


def test_service_clients_count_strictly_up_each_with_its_own_gid() -> None:
    one, two = ServiceClient(), ServiceClient()
    seqs = [naming.decode_attachment(one.attachment()).sequence_number for _ in range(3)]
    assert seqs == [1, 2, 3]
    assert naming.decode_attachment(two.attachment()).gid != one.gid


@dataclass
class FakeSample:
    key_expr: str
    payload: Any
    attachment: Any


class Raw:
    def __init__(self, data: bytes) -> None:
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data


def test_an_rmw_zenoh_sample_without_a_good_attachment_is_dropped() -> None:
    spec = {"endpoint": "tcp/127.0.0.1:1", "scheme": "rmw_zenoh", "distro": "jazzy", "speed": 1.0}
    entry = parse_robots({"robots": {"r": spec}}, "f").robots["r"]
    applied: list[Any] = []
    link = RobotLink("r", entry, lambda robot, change: applied.append(change))
    key = "0/battery_state/sensor_msgs::msg::dds_::BatteryState_/RIHS01_" + "0" * 64
    battery = Raw(m.encode(m.BatteryState(percentage=0.5)))
    link._on_sample("battery", FakeSample(key, battery, None))  # type: ignore[arg-type]
    link._on_sample("battery", FakeSample(key, battery, Raw(bytes(12))))  # type: ignore[arg-type]
    assert applied == []
    good = Raw(naming.Attachment(1, time.time_ns(), bytes(16)).encode())
    link._on_sample("battery", FakeSample(key, battery, good))  # type: ignore[arg-type]
    assert len(applied) == 1
    other_type = key.replace("BatteryState_", "Other_")
    link._on_sample("battery", FakeSample(other_type, battery, good))  # type: ignore[arg-type]
    assert len(applied) == 1


@pytest.fixture
def bridge_robot(tmp_path: Path) -> Iterator[Rig]:
    flags = ["--scheme", "bridge", "--distro", "humble", "--namespace", "/bot2"]
    yield from rig(tmp_path, *flags, "--result-timeout", "1.2", distro="humble")


def test_a_bridge_ending_the_held_get_result_at_its_timeout_is_asked_again(
    bridge_robot: Rig,
) -> None:
    side = bridge_robot.side
    side.wait(lambda s: s.status == "idle")
    # 60 m at 20 m/s: 3 s of driving, past two of the bridge's 1.2 s timeouts.
    ack = side.handler("r", Assign(request_id="q1", location=[60.0, 0.0], capabilities=["cam"]))
    assert ack.ok, ack.error
    done = side.wait(lambda s: s.task is not None and s.task.phase in ("done", "failed"), 10)
    assert done.task is not None and done.task.phase == "done", done.task
    assert len(bridge_robot.of("get_result_timeout")) >= 2


def test_a_robot_without_map_on_tf_is_placed_by_its_amcl_pose(tmp_path: Path) -> None:
    for rigged in rig(tmp_path, "--no-map-tf", "--x", "4", "--namespace", "/bot5"):
        state = rigged.side.wait(lambda s: s.status == "idle")
        assert state.position == [pytest.approx(4.0), pytest.approx(0.0)]
