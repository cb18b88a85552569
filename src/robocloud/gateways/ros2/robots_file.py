"""The gateway's robots file: one entry per ROS 2 robot, where to reach it and what it offers.

::

    {"robots": {
       "tb4-1": {"endpoint": "tcp/10.0.0.21:7447", "scheme": "rmw_zenoh", "domain": 0,
                 "namespace": "", "distro": "jazzy",
                 "offset": {"x": 100.0, "y": 20.0, "yaw": 1.5708}, "speed": 0.5,
                 "capabilities": {"camera": {"kind": "sensing", "time": 5, "cost": 1}}}},
     "travel_cost_per_m": 0.05, "min_battery": 10}

The robot's id is its key. Optional per robot: ``kind`` (default ``ros2``),
``action`` (the NavigateToPose action's name, default ``navigate_to_pose``),
``battery_topic`` (``battery_state``), ``tf_topic`` (``tf``), ``amcl_topic``
(``amcl_pose``, the pose when ``/tf`` has no map frame), the frames
(``map_frame``, ``odom_frame``, ``base_frame``), ``travel_cost_per_m``; names
are under ``namespace``. ``offset`` places the robot's map in the cloud's
frame: cloud = (x, y) + R(yaw) * map.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from robocloud.domain import Capability
from robocloud.domain.robot import Name, NonNegative, Speed
from robocloud.errors import InvalidInput
from robocloud.gateways.json_file import read_json_file, validated

MAX_ROBOTS = 1000
_STRICT = ConfigDict(extra="forbid", frozen=True)
Coordinate = Annotated[float, Field(ge=-1e7, le=1e7, allow_inf_nan=False)]
RosName = Annotated[str, Field(pattern=r"^[A-Za-z_~][A-Za-z0-9_/]*$", max_length=200)]
FrameName = Annotated[str, Field(pattern=r"^[A-Za-z0-9_./-]+$", max_length=200)]


class Offset(BaseModel):
    """The robot's map in the cloud's frame: cloud = (x, y) + R(yaw) * map."""

    model_config = _STRICT

    x: Coordinate = 0.0
    y: Coordinate = 0.0
    yaw: Annotated[float, Field(ge=-2 * math.pi, le=2 * math.pi, allow_inf_nan=False)] = 0.0

    def to_cloud(self, x: float, y: float) -> tuple[float, float]:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return self.x + c * x - s * y, self.y + s * x + c * y

    def to_map(self, x: float, y: float) -> tuple[float, float]:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        dx, dy = x - self.x, y - self.y
        return c * dx + s * dy, -s * dx + c * dy


class RobotEntry(BaseModel):
    model_config = _STRICT

    endpoint: Annotated[str, Field(min_length=1, max_length=300)] = Field(
        description="the robot's Zenoh router (rmw_zenoh) or bridge, e.g. tcp/10.0.0.21:7447"
    )
    scheme: Literal["rmw_zenoh", "bridge"]
    domain: Annotated[int, Field(ge=0, le=232)] = 0
    namespace: Annotated[str, Field(pattern=r"^(/?[A-Za-z_][A-Za-z0-9_]*)*/?$", max_length=200)] = (
        ""
    )
    distro: Literal["humble", "jazzy", "lyrical"]
    offset: Offset = Field(default_factory=Offset)
    speed: Speed = Field(description="m/s, for the ETA before the first feedback")
    capabilities: dict[Name, Capability] = Field(default_factory=dict)
    kind: Name = "ros2"
    travel_cost_per_m: NonNegative | None = None
    action: RosName = "navigate_to_pose"
    battery_topic: RosName = "battery_state"
    tf_topic: RosName = "tf"
    amcl_topic: RosName = "amcl_pose"
    map_frame: FrameName = "map"
    odom_frame: FrameName = "odom"
    base_frame: FrameName = "base_link"

    @field_validator("endpoint")
    @classmethod
    def _zenoh_endpoint(cls, value: str) -> str:
        protocol, sep, address = value.partition("/")
        if not sep or not protocol.isalpha() or not address:
            raise ValueError("must be a Zenoh endpoint, PROTOCOL/ADDRESS, e.g. tcp/10.0.0.21:7447")
        return value


class RobotsFile(BaseModel):
    model_config = _STRICT

    robots: Annotated[dict[Name, RobotEntry], Field(min_length=1, max_length=MAX_ROBOTS)]
    travel_cost_per_m: NonNegative = 0.05
    min_battery: Annotated[float, Field(ge=0.0, le=100.0, allow_inf_nan=False)] = 10.0

    def cost_per_m(self, robot: str) -> float:
        own = self.robots[robot].travel_cost_per_m
        return self.travel_cost_per_m if own is None else own


def parse_robots(data: object, source: str) -> RobotsFile:
    parsed = validated(RobotsFile, data, source, "--robots")
    endpoints: dict[str, str] = {}
    for robot, entry in parsed.robots.items():
        other = endpoints.setdefault(entry.endpoint, robot)
        if other != robot:
            raise InvalidInput(
                f"{source}: robots {other} and {robot} have the same endpoint "
                f"{entry.endpoint}; each robot is reached at its own.",
                "--robots",
            )
    return parsed


def load_robots(path: str) -> RobotsFile:
    """The file at ``path``, checked; each fault is an error with a sentence."""
    return parse_robots(read_json_file(path, "--robots", "robots file"), path)
