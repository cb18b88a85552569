"""The ROS 2 interfaces the gateway reads and writes, written from their documentation.

Each type is its ``.msg`` text (an action's goal, result and feedback and the
services and topics ROS 2 derives from an action are written out as the
messages they are). ``TYPES[distro]`` maps a type's name to its fields; the
Nav2 result is the one thing that differs between Humble and Jazzy:

- Humble: ``NavigateToPose_Result`` is ``std_msgs/Empty result``;
- Jazzy: ``uint16 error_code`` and ``string error_msg``.

Lyrical appends fields to the feedback; a robot configured as ``lyrical`` is
read as Jazzy with what follows the known fields skipped
(``TRAILING_ALLOWED``), never the other way round: a robot configured as
Humble or Jazzy that sends more than its distro's feedback is a wrong distro.
"""

from __future__ import annotations

from typing import Literal

Distro = Literal["humble", "jazzy", "lyrical"]
DISTROS: tuple[str, ...] = ("humble", "jazzy", "lyrical")

_COMMON = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec",
    "builtin_interfaces/Duration": "int32 sec\nuint32 nanosec",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id",
    # An empty message gets one member in its C and CDR form (rosidl's rule).
    "std_msgs/Empty": "uint8 structure_needs_at_least_one_member",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Quaternion": "float64 x\nfloat64 y\nfloat64 z\nfloat64 w",
    "geometry_msgs/Pose": "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation",
    "geometry_msgs/PoseStamped": "std_msgs/Header header\ngeometry_msgs/Pose pose",
    "geometry_msgs/Transform": (
        "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation"
    ),
    "geometry_msgs/TransformStamped": (
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform"
    ),
    "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms",
    "geometry_msgs/PoseWithCovariance": "geometry_msgs/Pose pose\nfloat64[36] covariance",
    "geometry_msgs/PoseWithCovarianceStamped": (
        "std_msgs/Header header\ngeometry_msgs/PoseWithCovariance pose"
    ),
    "sensor_msgs/BatteryState": """
        std_msgs/Header header
        float32 voltage
        float32 temperature
        float32 current
        float32 charge
        float32 capacity
        float32 design_capacity
        float32 percentage
        uint8 power_supply_status
        uint8 power_supply_health
        uint8 power_supply_technology
        bool present
        float32[] cell_voltage
        float32[] cell_temperature
        string location
        string serial_number""",
    "unique_identifier_msgs/UUID": "uint8[16] uuid",
    "action_msgs/GoalInfo": "unique_identifier_msgs/UUID goal_id\nbuiltin_interfaces/Time stamp",
    "action_msgs/GoalStatus": "action_msgs/GoalInfo goal_info\nint8 status",
    "action_msgs/GoalStatusArray": "action_msgs/GoalStatus[] status_list",
    "action_msgs/CancelGoal_Request": "action_msgs/GoalInfo goal_info",
    "action_msgs/CancelGoal_Response": "int8 return_code\naction_msgs/GoalInfo[] goals_canceling",
    "nav2_msgs/NavigateToPose_Goal": "geometry_msgs/PoseStamped pose\nstring behavior_tree",
    "nav2_msgs/NavigateToPose_Feedback": """
        geometry_msgs/PoseStamped current_pose
        builtin_interfaces/Duration navigation_time
        builtin_interfaces/Duration estimated_time_remaining
        int16 number_of_recoveries
        float32 distance_remaining""",
    "nav2_msgs/NavigateToPose_SendGoal_Request": (
        "unique_identifier_msgs/UUID goal_id\nnav2_msgs/NavigateToPose_Goal goal"
    ),
    "nav2_msgs/NavigateToPose_SendGoal_Response": "bool accepted\nbuiltin_interfaces/Time stamp",
    "nav2_msgs/NavigateToPose_GetResult_Request": "unique_identifier_msgs/UUID goal_id",
    "nav2_msgs/NavigateToPose_GetResult_Response": (
        "int8 status\nnav2_msgs/NavigateToPose_Result result"
    ),
    "nav2_msgs/NavigateToPose_FeedbackMessage": (
        "unique_identifier_msgs/UUID goal_id\nnav2_msgs/NavigateToPose_Feedback feedback"
    ),
}

_RESULT = {
    "humble": "std_msgs/Empty result",
    "jazzy": "uint16 error_code\nstring error_msg",
    "lyrical": "uint16 error_code\nstring error_msg",
}


def definitions(distro: str) -> dict[str, str]:
    """Every type's ``.msg`` text for ``distro``."""
    return {**_COMMON, "nav2_msgs/NavigateToPose_Result": _RESULT[distro]}


# Types a newer distro extends at the end: read as the configured distro's, the rest skipped.
TRAILING_ALLOWED: dict[str, frozenset[str]] = {
    "humble": frozenset(),
    "jazzy": frozenset(),
    "lyrical": frozenset({"nav2_msgs/NavigateToPose_FeedbackMessage"}),
}

# The DDS type names rmw_zenoh puts in its keys and liveliness tokens.
DDS_NAMES = {
    "send_goal": "nav2_msgs::action::dds_::NavigateToPose_SendGoal_",
    "get_result": "nav2_msgs::action::dds_::NavigateToPose_GetResult_",
    "cancel_goal": "action_msgs::srv::dds_::CancelGoal_",
    "feedback": "nav2_msgs::action::dds_::NavigateToPose_FeedbackMessage_",
    "status": "action_msgs::msg::dds_::GoalStatusArray_",
    "tf": "tf2_msgs::msg::dds_::TFMessage_",
    "battery": "sensor_msgs::msg::dds_::BatteryState_",
    "amcl": "geometry_msgs::msg::dds_::PoseWithCovarianceStamped_",
}

# action_msgs/GoalStatus
STATUS_UNKNOWN, STATUS_ACCEPTED, STATUS_EXECUTING, STATUS_CANCELING = 0, 1, 2, 3
STATUS_SUCCEEDED, STATUS_CANCELED, STATUS_ABORTED = 4, 5, 6
STATUS_NAMES = {
    0: "unknown", 1: "accepted", 2: "executing", 3: "canceling",
    4: "succeeded", 5: "canceled", 6: "aborted",
}  # fmt: skip
# action_msgs/CancelGoal_Response return codes
CANCEL_NONE, CANCEL_REJECTED, CANCEL_UNKNOWN_GOAL, CANCEL_TERMINATED = 0, 1, 2, 3
# sensor_msgs/BatteryState power_supply_status
POWER_CHARGING = 1
