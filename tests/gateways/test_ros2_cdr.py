"""The gateway's CDR codec against pycdr2 (the stand-in's), both ways, for Humble and Jazzy."""

from __future__ import annotations

from typing import Any

import pytest
from pycdr2 import IdlStruct

from robocloud.gateways.ros2 import interfaces as ros
from robocloud.gateways.ros2 import standin_cdr as m
from robocloud.gateways.ros2.cdr import CdrError, Codec

GOAL = bytes(range(1, 17))


def samples(distro: str) -> list[tuple[str, IdlStruct]]:
    pose = m.PoseStamped(m.Header(m.Time(17, 500), "map"), m.Pose(m.Point(1.5, -2.25, 0.0)))
    info = m.GoalInfo(m.uuid_of(GOAL), m.Time(3, 4))
    result: IdlStruct = (
        m.HumbleGetResultResponse(4)
        if distro == "humble"
        else m.JazzyGetResultResponse(6, m.JazzyResult(104, "no valid path"))
    )
    return [
        ("sensor_msgs/BatteryState", m.BatteryState(
            m.Header(m.Time(1, 2), "base_link"), voltage=14.75, percentage=0.625,
            power_supply_status=1, cell_voltage=[3.75, 3.5], location="bay", serial_number="s1")),
        ("tf2_msgs/TFMessage", m.tf_message([
            m.TransformStamped(m.Header(m.Time(5, 6), "map"), "odom",
                               m.Transform(m.Vector3(1.0, 0.5, 0.0), m.Quaternion(0, 0, 0.6, 0.8))),
            m.TransformStamped(m.Header(m.Time(5, 6), "odom"), "base_link", m.Transform()),
        ])),
        ("geometry_msgs/PoseWithCovarianceStamped", m.PoseWithCovarianceStamped(
            m.Header(m.Time(7, 8), "map"),
            m.PoseWithCovariance(pose.pose, [float(i) for i in range(36)]))),
        ("action_msgs/GoalStatusArray", m.status_array([m.GoalStatus(info, 2)])),
        ("action_msgs/CancelGoal_Request", m.CancelGoalRequest(info)),
        ("action_msgs/CancelGoal_Response", m.cancel_response(0, [info, info])),
        ("nav2_msgs/NavigateToPose_SendGoal_Request",
         m.SendGoalRequest(m.uuid_of(GOAL), m.NavigateGoal(pose, "bt.xml"))),
        ("nav2_msgs/NavigateToPose_SendGoal_Response", m.SendGoalResponse(True, m.Time(9, 10))),
        ("nav2_msgs/NavigateToPose_GetResult_Request", m.GetResultRequest(m.uuid_of(GOAL))),
        ("nav2_msgs/NavigateToPose_GetResult_Response", result),
        ("nav2_msgs/NavigateToPose_FeedbackMessage", m.FeedbackMessage(
            m.uuid_of(GOAL), m.Feedback(pose, m.Duration(12, 0), m.Duration(3, 250_000_000),
                                        2, 4.5))),
    ]  # fmt: skip


@pytest.mark.parametrize("distro", ["humble", "jazzy"])
def test_every_type_round_trips_both_ways_byte_for_byte(distro: str) -> None:
    codec = Codec(ros.definitions(distro))
    for typename, message in samples(distro):
        theirs = m.encode(message)
        decoded = codec.decode(typename, theirs)
        ours = codec.encode(typename, decoded)
        assert ours == theirs, typename
        assert type(message).deserialize(ours) == message, typename


def test_the_values_read_are_the_values_written() -> None:
    codec = Codec(ros.definitions("jazzy"))
    fb = codec.decode("nav2_msgs/NavigateToPose_FeedbackMessage", m.encode(samples("jazzy")[-1][1]))
    assert bytes(fb["goal_id"]["uuid"]) == GOAL
    assert fb["feedback"]["distance_remaining"] == 4.5
    assert fb["feedback"]["estimated_time_remaining"] == {"sec": 3, "nanosec": 250_000_000}
    assert fb["feedback"]["current_pose"]["header"]["frame_id"] == "map"
    battery = codec.decode("sensor_msgs/BatteryState", m.encode(samples("jazzy")[0][1]))
    assert battery["percentage"] == pytest.approx(0.625)
    assert battery["serial_number"] == "s1"


def test_the_result_of_one_distro_does_not_decode_as_the_other() -> None:
    humble, jazzy = Codec(ros.definitions("humble")), Codec(ros.definitions("jazzy"))
    typename = "nav2_msgs/NavigateToPose_GetResult_Response"
    jazzy_bytes = m.encode(dict(samples("jazzy"))[typename])
    humble_bytes = m.encode(dict(samples("humble"))[typename])
    with pytest.raises(CdrError, match="more than its type"):
        humble.decode(typename, jazzy_bytes)
    with pytest.raises(CdrError):
        jazzy.decode(typename, humble_bytes)
    result = jazzy.decode(typename, jazzy_bytes)
    assert result == {"status": 6, "result": {"error_code": 104, "error_msg": "no valid path"}}


@pytest.mark.parametrize("configured", ["humble", "jazzy"])
def test_a_lyrical_feedback_is_refused_by_humble_and_jazzy_and_read_as_lyrical(
    configured: str,
) -> None:
    lyrical = m.encode(m.LyricalFeedbackMessage(m.uuid_of(GOAL), m.LyricalFeedback(
        distance_remaining=7.0, tracking_error=0.1, behavior="follow")))  # fmt: skip
    typename = "nav2_msgs/NavigateToPose_FeedbackMessage"
    with pytest.raises(CdrError, match="bytes more than its type"):
        Codec(ros.definitions(configured)).decode(typename, lyrical)
    read = Codec(ros.definitions("lyrical")).decode(typename, lyrical, trailing=True)
    assert read["feedback"]["distance_remaining"] == 7.0


@pytest.mark.parametrize(
    ("data", "why"),
    [
        (b"", "no encapsulation header"),
        (b"\x01\x00\x00\x00" + bytes(40), "no encapsulation header"),
        (m.encode(m.GetResultRequest())[:10], "does not decode"),
    ],
)
def test_a_broken_message_is_an_error_with_a_sentence(data: bytes, why: str) -> None:
    with pytest.raises(CdrError, match=why):
        Codec(ros.definitions("jazzy")).decode("nav2_msgs/NavigateToPose_GetResult_Request", data)


def test_a_length_past_the_end_is_refused_before_anything_is_allocated() -> None:
    data = b"\x00\x01\x00\x00" + (1 << 30).to_bytes(4, "little")
    with pytest.raises(CdrError, match="runs past the message"):
        Codec(ros.definitions("jazzy")).decode("tf2_msgs/TFMessage", data)


def test_a_big_endian_message_is_read_too() -> None:
    message = m.GoalStatusArray([m.GoalStatus(m.GoalInfo(m.uuid_of(GOAL)), 4)])
    from pycdr2 import Endianness

    data: Any = message.serialize(endianness=Endianness.Big)
    read = Codec(ros.definitions("humble")).decode("action_msgs/GoalStatusArray", bytes(data))
    assert read["status_list"][0]["status"] == 4
