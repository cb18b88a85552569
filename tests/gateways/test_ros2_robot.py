"""One ROS 2 robot's state machine, fed by hand: no Zenoh, no clock but the one given."""

from __future__ import annotations

import math

import pytest

from robocloud.fleet.messages import Assign
from robocloud.gateways.ros2 import interfaces as ros
from robocloud.gateways.ros2.robot import RosRobot
from robocloud.gateways.ros2.robots_file import parse_robots

OTHER = bytes([9]) * 16


def robot(yaw: float = 0.0, distro: str = "jazzy") -> RosRobot:
    entry = parse_robots(
        {
            "robots": {
                "r": {
                    "endpoint": "tcp/127.0.0.1:7501",
                    "scheme": "rmw_zenoh",
                    "distro": distro,
                    "offset": {"x": 100.0, "y": 0.0, "yaw": yaw},
                    "speed": 2.0,
                    "capabilities": {"cam": {"kind": "sensing", "time": 4.0, "cost": 1.0}},
                }
            }
        },
        "f",
    ).robots["r"]
    r = RosRobot("r", entry)
    # odom at (1, 0.5) in the map, the base 1 m further along odom's x: (2, 0.5) in the map.
    r.on_transforms([("map", "odom", 1.0, 0.5, 0.0), ("odom", "base_link", 1.0, 0.0, 0.0)], 0.0)
    r.on_battery(0.75, 2, 0.0)
    return r


def assign(location: tuple[float, float] = (110.0, 0.5)) -> Assign:
    return Assign(request_id="q1", location=list(location), capabilities=["cam"])


def test_it_joins_offline_and_is_idle_once_the_action_server_is_visible() -> None:
    r = robot()
    state = r.state("c", 0.05, 0.0, 1.0)
    assert state is not None
    assert state.status == "offline"
    assert state.position == [pytest.approx(102.0), pytest.approx(0.5)]
    assert state.battery == pytest.approx(75.0)  # the fraction made a percent
    r.on_server(True, 0.1, "token")
    assert r.status(0.1) == "idle"


def test_a_robot_without_the_map_frame_says_what_is_missing() -> None:
    entry = robot().entry
    r = RosRobot("r", entry)
    r.on_transforms([("odom", "base_link", 1.0, 0.0, 0.0)], 0.0)
    assert r.state("c", 0.05, 0.0, 1.0) is None
    assert r.missing() == (
        "no base_link in map on /tf yet (map -> odom -> base_link), nor /amcl_pose"
    )
    r.on_transforms([("map", "odom", 0.0, 0.0, 0.0)], 0.0)
    assert r.missing() == "no battery on /battery_state yet"


def test_without_a_map_frame_on_tf_the_amcl_pose_places_the_robot() -> None:
    r = RosRobot("r", robot().entry)
    r.on_transforms([("odom", "base_link", 1.0, 0.0, 0.0)], 0.0)
    r.on_amcl("odom", 9.0, 9.0, 0.0)  # not in the map frame: not a map pose
    assert r.position() is None
    r.on_amcl("map", 3.0, -1.0, 0.0)
    assert r.position() == (pytest.approx(103.0), pytest.approx(-1.0))
    r.on_transforms([("map", "odom", 1.0, 0.5, 0.0)], 0.0)  # /tf wins once it has the map
    assert r.position() == (pytest.approx(102.0), pytest.approx(0.5))


def test_the_pose_composes_map_odom_base_link_and_the_offset() -> None:
    r = robot(yaw=math.pi / 2)
    r.on_transforms([("odom", "base_link", 1.0, 0.0, math.pi / 2)], 0.0)
    # base at (2, 0.5) in the map; a quarter turn: cloud = (100 - 0.5, 2).
    assert r.position() == (pytest.approx(99.5), pytest.approx(2.0))
    r.on_transforms([("odom", "base_link", 1.0, 0.0, 0.0)], 0.0)
    job = r.take(assign((99.5, 12.0)), 0.0)
    assert job.goal_map == (pytest.approx(12.0), pytest.approx(0.5))


def test_a_task_travels_works_and_is_done_with_progress_that_never_goes_back() -> None:
    r = robot()
    r.on_server(True, 0.0, "token")
    assert r.refuse(assign(), 10.0, 0.0) is None
    job = r.take(assign(), 0.0)
    assert r.status(0.0) == "busy"
    seen = []
    for t, distance in ((1.0, 6.0), (2.0, 4.0), (3.0, 2.0)):
        r.on_feedback(job.goal_id, distance, distance / 2.0, t)
        r.tick(t)
        seen.append(job.progress)
    r.on_feedback(OTHER, 100.0, 50.0, 3.5)  # someone else's goal: not ours
    r.on_result(job.goal_id, ros.STATUS_SUCCEEDED, "", 4.0)
    assert job.phase == "work"
    r.tick(6.0)
    seen.append(job.progress)
    assert seen == sorted(seen) and seen[-1] < 1.0
    r.on_battery(0.75, 2, 8.0)  # still heard from
    r.tick(8.1)
    assert r.job is None and r.finished is not None and r.finished.phase == "done"
    assert r.status(8.1) == "idle"


@pytest.mark.parametrize(
    ("event", "reason"),
    [
        ("abort", "navigation aborted: error 104 no valid path."),
        ("preempt", "navigation preempted by another goal (09090909"),
        ("vanish", "Nav2's action server navigate_to_pose vanished."),
        ("lost", "Nav2's action server navigate_to_pose vanished."),
        ("reject", "Nav2 rejected the goal."),
        ("fault", "its nav2_msgs/NavigateToPose_FeedbackMessage does not decode as jazzy"),
    ],
)
def test_a_task_fails_with_its_reason(event: str, reason: str) -> None:
    r = robot()
    r.on_server(True, 0.0, "token")
    job = r.take(assign(), 0.0)
    job.sent = True
    if event == "abort":
        r.on_result(job.goal_id, ros.STATUS_ABORTED, "error 104 no valid path", 0.6)
        assert r.job is job  # a preempting goal's status may still come
        r.tick(1.0)
        assert r.job is job
        r.tick(1.2)
    elif event == "preempt":
        r.on_status([(job.goal_id, ros.STATUS_EXECUTING)], 0.5)
        r.on_result(job.goal_id, ros.STATUS_ABORTED, "", 0.8)  # the result came first
        r.on_status([(job.goal_id, ros.STATUS_ABORTED), (OTHER, ros.STATUS_EXECUTING)], 1.0)
    elif event == "vanish":
        r.on_server(False, 1.0, "token gone")
    elif event == "lost":
        r.on_result_lost(job.goal_id, 1.0)
    elif event == "reject":
        r.on_goal_response(job.goal_id, False, 1.0)
    else:
        r.on_fault("its nav2_msgs/NavigateToPose_FeedbackMessage does not decode as jazzy.", 1.0)
    assert r.job is None and r.finished is not None
    assert r.finished.phase == "failed"
    assert r.finished.reason is not None and r.finished.reason.startswith(reason)
    state = r.state("c", 0.05, 1.0, 1.0)
    assert state is not None and state.task is not None and state.task.reason == r.finished.reason
    again = r.refuse(Assign(request_id="q2", location=[0, 0], capabilities=["cam"]), 10, 1.5)
    # Nav2 gone, a fault or another user's goal: not chosen; after an abort or a
    # rejection Nav2 is there and free, and another task may go better.
    assert (again is None) == (event in ("abort", "reject")), again
    if event == "fault":
        assert r.cancels == [job.goal_id]  # the robot must not go on driving for it
    if event in ("vanish", "lost"):
        assert r.status(1.0) == "offline"
        r.on_server(True, 2.0, "token back")
        assert r.status(2.0) == "idle"


def test_cancel_drops_the_task_at_once_and_names_the_goal() -> None:
    r = robot()
    r.on_server(True, 0.0, "token")
    job = r.take(assign(), 0.0)
    refusal, canceled = r.cancel("q-other")
    assert refusal is not None and "not on request q-other" in refusal and canceled is None
    refusal, canceled = r.cancel("q1")
    assert refusal is None and canceled is job
    assert r.job is None and r.status(0.1) == "idle"
    assert r.cancel("q1") == (None, None)


def test_what_it_refuses() -> None:
    r = robot()
    assert "not visible" in (r.refuse(assign(), 10.0, 0.0) or "")
    r.on_server(True, 0.0, "token")
    lacking = Assign(request_id="q1", location=[0, 0], capabilities=["arm"])
    assert "lacks the capability arm" in (r.refuse(lacking, 10.0, 0.0) or "")
    assert "below the 80% a task needs" in (r.refuse(assign(), 80.0, 0.0) or "")
    r.on_status([(OTHER, ros.STATUS_EXECUTING)], 0.0)
    assert "another user's goal" in (r.refuse(assign(), 10.0, 0.0) or "")
    r.on_battery(1.5, 2, 0.0)
    assert r.battery == pytest.approx(75.0) and r.notes[-1].endswith("not a fraction from 0 to 1")
    assert r.status(STALE := 10.0) == "offline", STALE
