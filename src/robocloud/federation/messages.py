"""The JSON messages between IaaS nodes on the overlay (the thesis's Task Delegator Engine).

Every message is a Zenoh query to one cloud's key (or to ``robocloud/*/...``
for all of them) whose payload and reply are these models:

=================================  ==========================  ======================
key                                payload                     reply
=================================  ==========================  ======================
``robocloud/<cloud>/info``         (none)                      ``CloudInfo``
``robocloud/<cloud>/idle``         ``IdleQuery``               ``IdleReply``
``robocloud/<cloud>/fleet``        (none)                      ``FleetReply``
``robocloud/<cloud>/reserve``      ``Reservation``             ``ReserveReply``
``robocloud/<cloud>/confirm``      ``Reservation``             ``ReserveReply``
``robocloud/<cloud>/release``      ``Release``                 ``Done``
``robocloud/<cloud>/dispatch``     ``Dispatch``                ``Ack`` (the robot's)
``robocloud/<cloud>/cancel``       ``Release``                 ``Done``
``robocloud/<cloud>/status``       ``StatusQuery``             ``RequestStatus``
=================================  ==========================  ======================

A cloud announces itself with the liveliness token
``robocloud/federation/clouds/<cloud>``; robots' states are on their home
cloud's keys (``robocloud/<cloud>/robots/<id>/state``) and any IaaS that uses
a robot subscribes to them. Commands to a robot go only through its home
cloud, which checks that the asking cloud is trusted and holds the robot.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from robocloud.domain import Robot
from robocloud.domain.robot import Name
from robocloud.fleet.messages import Assign

_WIRE = ConfigDict(extra="ignore", frozen=True)

CLOUDS_TOKEN = "robocloud/federation/clouds"


class CloudInfo(BaseModel):
    model_config = _WIRE

    cloud: Name
    robots: int = Field(ge=0, description="robots heard from since the IaaS started")
    idle: int = Field(ge=0, description="of those, idle and not reserved")
    offline: int = Field(0, ge=0, description="of those, offline or silent")
    api: str | None = Field(None, description="the cloud's HTTP API, if it says")


class IdleQuery(BaseModel):
    """The task's filter, so only useful robots travel (Algorithm 2 at each home)."""

    model_config = _WIRE

    origin: Name
    min_battery: float = Field(0.0, ge=0.0, le=100.0)
    capabilities: list[Name] = Field(default_factory=list)


class IdleReply(BaseModel):
    model_config = _WIRE

    cloud: Name
    robots: list[Robot]


class FleetReply(BaseModel):
    model_config = _WIRE

    cloud: Name
    robots: list[dict[str, Any]]


class Reservation(BaseModel):
    """Hold robots of the home cloud for a request of ``origin``; a lease until confirmed."""

    model_config = _WIRE

    origin: Name
    request_id: Name
    robots: list[Name]
    lease_seconds: float | None = Field(None, gt=0)


class ReserveReply(BaseModel):
    model_config = _WIRE

    taken: list[Name] = Field(default_factory=list, description="robots another request holds")
    error: str | None = None


class Release(BaseModel):
    model_config = _WIRE

    origin: Name
    request_id: Name
    robots: list[Name] | None = None  # None: every robot of the request
    why: str | None = None


class Done(BaseModel):
    model_config = _WIRE

    ok: bool = True
    error: str | None = None


class Dispatch(BaseModel):
    model_config = _WIRE

    origin: Name
    robot: Name
    command: Assign


class StatusQuery(BaseModel):
    model_config = _WIRE

    home: Name
    request_id: Name


class RequestStatus(BaseModel):
    """What the origin says of a request a home holds robots for."""

    model_config = _WIRE

    request_id: Name
    known: bool
    final: bool = False
    robots: list[Name] = Field(default_factory=list, description="its robots now")
