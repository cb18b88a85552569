"""The stand-in robot's messages, encoded with pycdr2 (not the gateway's codec).

Each ROS 2 type the stand-in speaks is a pycdr2 ``IdlStruct`` written here
from the interface documentation, so the gateway's own codec (``cdr.py``) and
this one check each other: a field the gateway placed wrongly does not decode
here, and the other way round. The ``Humble*``, ``Jazzy*`` and ``Lyrical*``
classes hold what differs between distros (the Nav2 result from Humble to
Jazzy; the stand-in's Lyrical feedback, with two fields appended).
"""

# mypy: disable-error-code="type-arg, assignment, arg-type, valid-type, no-any-return"
# (pycdr2's annotations are types of its own, which mypy does not read as Python's.)
# No "from __future__ import annotations": pycdr2 reads the annotations as types.

from dataclasses import dataclass, field

from pycdr2 import IdlStruct
from pycdr2.types import (
    array,
    float32,
    float64,
    int8,
    int16,
    int32,
    sequence,
    uint8,
    uint16,
    uint32,
)


@dataclass
class Time(IdlStruct, typename="builtin_interfaces/msg/Time"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Duration(IdlStruct, typename="builtin_interfaces/msg/Duration"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Header(IdlStruct, typename="std_msgs/msg/Header"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class Empty(IdlStruct, typename="std_msgs/msg/Empty"):
    structure_needs_at_least_one_member: uint8 = 0


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs/msg/Vector3"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Point(IdlStruct, typename="geometry_msgs/msg/Point"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs/msg/Quaternion"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class Pose(IdlStruct, typename="geometry_msgs/msg/Pose"):
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass
class PoseStamped(IdlStruct, typename="geometry_msgs/msg/PoseStamped"):
    header: Header = field(default_factory=Header)
    pose: Pose = field(default_factory=Pose)


@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs/msg/PoseWithCovariance"):
    pose: Pose = field(default_factory=Pose)
    covariance: array[float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class PoseWithCovarianceStamped(IdlStruct, typename="geometry_msgs/msg/PoseWithCovarianceStamped"):
    header: Header = field(default_factory=Header)
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)


@dataclass
class Transform(IdlStruct, typename="geometry_msgs/msg/Transform"):
    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs/msg/TransformStamped"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: Transform = field(default_factory=Transform)


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs/msg/TFMessage"):
    transforms: sequence[TransformStamped] = field(default_factory=list)


@dataclass
class BatteryState(IdlStruct, typename="sensor_msgs/msg/BatteryState"):
    header: Header = field(default_factory=Header)
    voltage: float32 = 0.0
    temperature: float32 = 0.0
    current: float32 = 0.0
    charge: float32 = 0.0
    capacity: float32 = 0.0
    design_capacity: float32 = 0.0
    percentage: float32 = 0.0
    power_supply_status: uint8 = 0
    power_supply_health: uint8 = 0
    power_supply_technology: uint8 = 0
    present: bool = True
    cell_voltage: sequence[float32] = field(default_factory=list)
    cell_temperature: sequence[float32] = field(default_factory=list)
    location: str = ""
    serial_number: str = ""


@dataclass
class UUID(IdlStruct, typename="unique_identifier_msgs/msg/UUID"):
    uuid: array[uint8, 16] = field(default_factory=lambda: bytes(16))


@dataclass
class GoalInfo(IdlStruct, typename="action_msgs/msg/GoalInfo"):
    goal_id: UUID = field(default_factory=UUID)
    stamp: Time = field(default_factory=Time)


@dataclass
class GoalStatus(IdlStruct, typename="action_msgs/msg/GoalStatus"):
    goal_info: GoalInfo = field(default_factory=GoalInfo)
    status: int8 = 0


@dataclass
class GoalStatusArray(IdlStruct, typename="action_msgs/msg/GoalStatusArray"):
    status_list: sequence[GoalStatus] = field(default_factory=list)


@dataclass
class CancelGoalRequest(IdlStruct, typename="action_msgs/srv/CancelGoal_Request"):
    goal_info: GoalInfo = field(default_factory=GoalInfo)


@dataclass
class CancelGoalResponse(IdlStruct, typename="action_msgs/srv/CancelGoal_Response"):
    return_code: int8 = 0
    goals_canceling: sequence[GoalInfo] = field(default_factory=list)


@dataclass
class NavigateGoal(IdlStruct, typename="nav2_msgs/action/NavigateToPose_Goal"):
    pose: PoseStamped = field(default_factory=PoseStamped)
    behavior_tree: str = ""


@dataclass
class SendGoalRequest(IdlStruct, typename="nav2_msgs/action/NavigateToPose_SendGoal_Request"):
    goal_id: UUID = field(default_factory=UUID)
    goal: NavigateGoal = field(default_factory=NavigateGoal)


@dataclass
class SendGoalResponse(IdlStruct, typename="nav2_msgs/action/NavigateToPose_SendGoal_Response"):
    accepted: bool = False
    stamp: Time = field(default_factory=Time)


@dataclass
class GetResultRequest(IdlStruct, typename="nav2_msgs/action/NavigateToPose_GetResult_Request"):
    goal_id: UUID = field(default_factory=UUID)


# -- what differs between distros ----------------------------------------------------


@dataclass
class HumbleResult(IdlStruct, typename="nav2_msgs/action/NavigateToPose_Result"):
    result: Empty = field(default_factory=Empty)


@dataclass
class JazzyResult(IdlStruct, typename="nav2_msgs/action/NavigateToPose_Result"):
    error_code: uint16 = 0
    error_msg: str = ""


@dataclass
class HumbleGetResultResponse(
    IdlStruct, typename="nav2_msgs/action/NavigateToPose_GetResult_Response"
):
    status: int8 = 0
    result: HumbleResult = field(default_factory=HumbleResult)


@dataclass
class JazzyGetResultResponse(
    IdlStruct, typename="nav2_msgs/action/NavigateToPose_GetResult_Response"
):
    status: int8 = 0
    result: JazzyResult = field(default_factory=JazzyResult)


@dataclass
class Feedback(IdlStruct, typename="nav2_msgs/action/NavigateToPose_Feedback"):
    current_pose: PoseStamped = field(default_factory=PoseStamped)
    navigation_time: Duration = field(default_factory=Duration)
    estimated_time_remaining: Duration = field(default_factory=Duration)
    number_of_recoveries: int16 = 0
    distance_remaining: float32 = 0.0


@dataclass
class LyricalFeedback(IdlStruct, typename="nav2_msgs/action/NavigateToPose_Feedback"):
    """Jazzy's feedback and two more fields (the stand-in's model of a newer distro)."""

    current_pose: PoseStamped = field(default_factory=PoseStamped)
    navigation_time: Duration = field(default_factory=Duration)
    estimated_time_remaining: Duration = field(default_factory=Duration)
    number_of_recoveries: int16 = 0
    distance_remaining: float32 = 0.0
    tracking_error: float32 = 0.0
    behavior: str = ""


@dataclass
class FeedbackMessage(IdlStruct, typename="nav2_msgs/action/NavigateToPose_FeedbackMessage"):
    goal_id: UUID = field(default_factory=UUID)
    feedback: Feedback = field(default_factory=Feedback)


@dataclass
class LyricalFeedbackMessage(IdlStruct, typename="nav2_msgs/action/NavigateToPose_FeedbackMessage"):
    goal_id: UUID = field(default_factory=UUID)
    feedback: LyricalFeedback = field(default_factory=LyricalFeedback)


def duration(seconds: float) -> Duration:
    whole = int(seconds)
    return Duration(whole, int((seconds - whole) * 1e9))


def uuid_of(raw: bytes) -> UUID:
    return UUID(bytes(raw))


def raw_uuid(uuid: UUID) -> bytes:
    return bytes(uuid.uuid)  # type: ignore[call-overload]


def tf_message(transforms: list[TransformStamped]) -> TFMessage:
    return TFMessage(transforms)


def status_array(statuses: list[GoalStatus]) -> GoalStatusArray:
    return GoalStatusArray(statuses)


def cancel_response(code: int, goals: list[GoalInfo]) -> CancelGoalResponse:
    return CancelGoalResponse(code, goals)


def encode(message: IdlStruct) -> bytes:
    """CDR, little-endian, with its encapsulation header, as ROS 2 sends it."""
    return bytes(message.serialize())


_ = (float32, int16, uint16)  # the types above use them; ruff reads annotations as used
