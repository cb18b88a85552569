"""The bricks file: each NXT robot, how to reach it, how it is built, what it can do.

::

    {"robots": {
       "tribot": {
         "kind": "tribot",
         "reach": {"bluetooth": "00:16:53:0A:1B:2C"},      or {"tcp": "127.0.0.1:7101"}
         "battery": "aa",                                   or "rechargeable"
         "build": {"left": "B", "right": "C", "wheel_diameter": 0.056, "track_width": 0.112,
                   "drive_power": 75, "speed": 0.33,
                   "arm": {"port": "A", "open": 0, "close": 90, "power": 40}},
         "sensors": {"1": "touch", "2": "sound", "3": "light", "4": "ultrasonic"},
         "start": {"x": 0.0, "y": 0.0, "heading": 0.0},
         "travel_cost_per_m": 0.05,
         "capabilities": {
           "grabber": {"kind": "actuating", "time": 4.0, "cost": 3.0,
                       "steps": [{"arm": "open"}, {"arm": "close"}]},
           "light": {"kind": "sensing", "time": 5.0, "cost": 1.0,
                     "steps": [{"search": {"sensor": 3, "above": 50, "max_distance": 0.5}}]}}}},
     "min_battery": 10.0}

- ``reach``: the brick's Bluetooth address (paired beforehand; RFCOMM channel
  1), or ``host:port`` of a stand-in brick (``robocloud nxt-brick``).
- ``build``: the drive motors' ports (A, B, C), the wheels' diameter and the
  distance between them (metres), the power it drives at, ``speed`` (m/s at
  that power, measured once by the operator: it is what the IaaS plans with),
  and the arm's motor with its open and close angles (degrees of the motor from
  where it stands when the gateway connects, which it takes as ``open``).
- ``sensors``: input port 1 to 4 -> light, touch, ultrasonic or sound.
- ``start``: the pose where the brick stands when the gateway connects, in the
  federation's frame (metres; heading in degrees, 0 along +x, counter-clockwise).
- ``capabilities``: name -> kind, time, cost (what the IaaS plans with) and the
  steps the brick carries out at the task's location, in order:
  ``{"arm": "open"|"close"}``; ``{"motor": "A", "power": 50, "degrees": 180}``;
  ``{"search": {"sensor": 3, "above": 50, "max_distance": 0.5}}`` (drive ahead
  until the light sensor on that port reads above the threshold, at most that
  far); ``{"wait": 1.5}`` (seconds).

Every fault is refused with a sentence naming its field (exit code 2).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from robocloud.domain import Capability
from robocloud.domain.robot import Coordinate, Name, NonNegative, Speed
from robocloud.errors import InvalidInput
from robocloud.fleet import keys
from robocloud.gateways.json_file import read_json_file, validated

MAX_BRICKS = 64  # one Bluetooth adapter links up to 7; a few adapters, or stand-ins

MotorPort = Literal["A", "B", "C"]
SensorPort = Literal["1", "2", "3", "4"]
SensorKind = Literal["light", "touch", "ultrasonic", "sound"]
Power = Annotated[int, Field(ge=1, le=100)]
Metres = Annotated[float, Field(gt=0.0, le=10.0, allow_inf_nan=False)]
BLUETOOTH_ADDRESS = r"^[0-9A-Fa-f]{2}(:[0-9A-Fa-f]{2}){5}$"

_STRICT = ConfigDict(extra="forbid", frozen=True)


class Reach(BaseModel):
    model_config = _STRICT

    bluetooth: Annotated[str, Field(pattern=BLUETOOTH_ADDRESS)] | None = Field(
        None, description="the brick's Bluetooth address, e.g. 00:16:53:0A:1B:2C"
    )
    tcp: str | None = Field(None, description="host:port of a stand-in brick")

    @model_validator(mode="after")
    def _one(self) -> Reach:
        if (self.bluetooth is None) == (self.tcp is None):
            raise ValueError("give exactly one of bluetooth and tcp")
        if self.tcp is not None:
            host, sep, port = self.tcp.rpartition(":")
            if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
                raise ValueError(f"tcp {self.tcp!r} is not host:port, e.g. 127.0.0.1:7101")
        return self

    def tcp_address(self) -> tuple[str, int]:
        assert self.tcp is not None
        host, _, port = self.tcp.rpartition(":")
        return host.strip("[]"), int(port)

    def describe(self) -> str:
        return f"Bluetooth {self.bluetooth}" if self.bluetooth else f"tcp {self.tcp}"


class Arm(BaseModel):
    model_config = _STRICT

    port: MotorPort
    open: int = Field(0, ge=-3600, le=3600, description="degrees of the arm's motor")
    close: int = Field(ge=-3600, le=3600, description="degrees of the arm's motor")
    power: Power = 40


class Build(BaseModel):
    model_config = _STRICT

    left: MotorPort
    right: MotorPort
    wheel_diameter: Metres = Field(description="metres (the NXT kit's wheel: 0.056)")
    track_width: Metres = Field(description="metres between the wheels' contact points")
    drive_power: Power = 75
    speed: Speed = Field(0.3, description="m/s at drive_power, measured")
    arm: Arm | None = None

    @model_validator(mode="after")
    def _ports(self) -> Build:
        used = [self.left, self.right, *([self.arm.port] if self.arm else [])]
        if len(set(used)) != len(used):
            raise ValueError(f"the motors must be on different ports, not {', '.join(used)}")
        return self


class Pose(BaseModel):
    model_config = _STRICT

    x: Coordinate = 0.0
    y: Coordinate = 0.0
    heading: Annotated[float, Field(ge=-360.0, le=360.0, allow_inf_nan=False)] = 0.0


class Search(BaseModel):
    model_config = _STRICT

    sensor: Annotated[int, Field(ge=1, le=4)] = Field(description="the light sensor's port")
    above: Annotated[int, Field(ge=0, le=100)] = Field(description="percent of full scale")
    max_distance: Metres = 0.5


class Step(BaseModel):
    """One step of a capability: exactly one of ``arm``, ``motor``, ``search``, ``wait``."""

    model_config = _STRICT

    arm: Literal["open", "close"] | None = None
    motor: MotorPort | None = None
    power: Annotated[int, Field(ge=-100, le=100)] | None = None
    degrees: Annotated[int, Field(ge=1, le=36_000)] | None = None
    search: Search | None = None
    wait: Annotated[float, Field(ge=0.0, le=3600.0, allow_inf_nan=False)] | None = None

    @model_validator(mode="after")
    def _one(self) -> Step:
        given = [k for k in ("arm", "motor", "search", "wait") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("a step is exactly one of arm, motor, search and wait")
        if (self.motor is None) != (self.power is None and self.degrees is None):
            raise ValueError("power and degrees go with motor")
        if self.motor is not None and (self.power is None or self.degrees is None):
            raise ValueError("a motor step needs power and degrees")
        return self


class CapabilitySteps(BaseModel):
    model_config = _STRICT

    kind: Literal["sensing", "actuating"]
    time: NonNegative = Field(description="seconds of work at the task's location, planned")
    cost: NonNegative
    steps: Annotated[list[Step], Field(min_length=1, max_length=32)]

    def capability(self) -> Capability:
        return Capability(kind=self.kind, time=self.time, cost=self.cost)


class BrickConfig(BaseModel):
    model_config = _STRICT

    kind: Name = "nxt"
    reach: Reach
    battery: Literal["aa", "rechargeable"] = "aa"
    build: Build
    sensors: dict[SensorPort, SensorKind] = Field(default_factory=dict)
    start: Pose = Field(default_factory=Pose)
    travel_cost_per_m: NonNegative = 0.05
    capabilities: dict[Name, CapabilitySteps] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _steps_fit(self) -> BrickConfig:
        for name, capability in self.capabilities.items():
            for i, step in enumerate(capability.steps):
                where = f"capabilities.{name}.steps[{i}]"
                if step.arm is not None and self.build.arm is None:
                    raise ValueError(f"{where} moves the arm, but build has no arm")
                drive = (self.build.left, self.build.right)
                if step.motor is not None and step.motor in drive:
                    raise ValueError(f"{where} turns motor {step.motor}, a drive motor")
                if step.search is not None:
                    port = str(step.search.sensor)
                    if self.sensors.get(port) != "light":  # type: ignore[call-overload]
                        raise ValueError(
                            f"{where} searches with sensor port {port}, which sensors does not "
                            "list as a light sensor"
                        )
        return self

    def offered(self) -> dict[str, Capability]:
        return {name: c.capability() for name, c in self.capabilities.items()}


class BricksFile(BaseModel):
    model_config = _STRICT

    robots: Annotated[dict[str, BrickConfig], Field(min_length=1, max_length=MAX_BRICKS)]
    min_battery: Annotated[float, Field(ge=0.0, le=100.0, allow_inf_nan=False)] = 10.0


def parse_bricks(data: object, source: str) -> BricksFile:
    """``data`` (the file's JSON) checked: InvalidInput naming the field at fault."""
    bricks = validated(BricksFile, data, source, "--bricks")
    for robot in bricks.robots:
        try:
            keys.check_chunk(robot, "robot")
        except InvalidInput as error:
            raise InvalidInput(f"{source}: robots: {error.message}", "--bricks") from None
    addresses = [b.reach.describe() for b in bricks.robots.values()]
    twice = sorted({a for a in addresses if addresses.count(a) > 1})
    if twice:
        raise InvalidInput(
            f"{source}: robots: two robots are the same brick ({twice[0]}).", "--bricks"
        )
    return bricks


def load_bricks(path: str) -> BricksFile:
    return parse_bricks(read_json_file(path, "--bricks", "bricks file"), path)
