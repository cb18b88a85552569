"""The JSON messages between IaaS nodes on the overlay (the thesis's Task Delegator Engine).

Every message is a Zenoh query to one cloud's key (or to ``robocloud/*/...``
for all of them) whose payload and reply are these models. Questions are
open to every member of the federation; commands are sent on a key that
names their sender (``robocloud.federation.keys``), and the home takes the
origin from that key, never from the payload:

==============================================  ==================  ======================
key                                             payload             reply
==============================================  ==================  ======================
``robocloud/<cloud>/info``                      (none)              ``CloudInfo``
``robocloud/<cloud>/idle``                      ``IdleQuery``       ``IdleReply``
``robocloud/<cloud>/fleet``                     (none)              ``FleetReply``
``robocloud/<origin>/status``                   ``StatusQuery``     ``StatusReply``
``robocloud/<home>/from/<origin>/reserve``      ``Reservation``     ``ReserveReply``
``robocloud/<home>/from/<origin>/confirm``      ``Reservation``     ``ReserveReply``
``robocloud/<home>/from/<origin>/release``      ``Release``         ``Done``
``robocloud/<home>/from/<origin>/dispatch``     ``Dispatch``        ``Ack`` (the robot's)
``robocloud/<home>/from/<origin>/cancel``       ``Release``         ``Done``
``robocloud/<home>/from/<origin>/loans``        ``LoanQuery``       ``LoanReply``
==============================================  ==================  ======================

A cloud announces itself with the liveliness token
``robocloud/federation/clouds/<cloud>``; robots' states are on their home
cloud's keys (``robocloud/<cloud>/robots/<id>/state``) and any IaaS that uses
a robot subscribes to them. Commands to a robot go only through its home
cloud, which checks that the sender is trusted and holds the robot (a loan).

Lists are bounded (``MAX_ITEMS``) so a well-formed but absurd message is
refused before any work; the overlay also refuses payloads over
``MAX_MESSAGE_BYTES``. Fields a receiver does not know are ignored.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated, Any

import msgspec
from pydantic import BaseModel, ConfigDict, Field

from robocloud.domain import Robot
from robocloud.domain.records import (
    CheckedName,
    CheckedRobotRecord,
    RecordName,
    RobotRecord,
    may_hold_control_characters,
)
from robocloud.domain.robot import Name
from robocloud.fleet.messages import Ack, Assign, Start

_WIRE = ConfigDict(extra="ignore", frozen=True)

MAX_ITEMS = 1000  # robots, request ids or loans in one message
MAX_MESSAGE_BYTES = 1 << 20  # a reply of 1,000 idle robots is about 400 KB
Why = Annotated[str, Field(max_length=500)]


class CloudInfo(BaseModel):
    model_config = _WIRE

    cloud: Name
    robots: int = Field(ge=0, description="robots heard from since the IaaS started")
    idle: int = Field(ge=0, description="of those, idle and not reserved")
    offline: int = Field(0, ge=0, description="of those, offline or silent")
    api: str | None = Field(None, description="the cloud's HTTP API, if it says")
    capabilities: list[Name] = Field(
        default_factory=list,
        max_length=MAX_ITEMS,
        description="every capability name its robots have announced since its IaaS started",
    )


class IdleQuery(BaseModel):
    """The task's filter, so only useful robots travel (Algorithm 2 at each home).

    A question, so ``origin`` is what the asker claims: it only decides
    whether a home that trusts nobody by that name answers with no robots.
    """

    model_config = _WIRE

    origin: Name
    min_battery: float = Field(0.0, ge=0.0, le=100.0)
    capabilities: list[Name] = Field(default_factory=list, max_length=MAX_ITEMS)


class IdleReply(BaseModel):
    """A home's idle robots that pass the query's filter (its schema; see ``IdleRobots``)."""

    model_config = _WIRE

    cloud: Name
    robots: list[Robot] = Field(max_length=MAX_ITEMS)


class IdleRobots(msgspec.Struct, frozen=True):
    """An ``IdleReply`` as the asker decodes it: its robots as ``RobotRecord``.

    Hundreds of robots come in each reply, for every selection; pydantic took
    about 3 microseconds a robot to build them, msgspec checks the same
    limits (``Robot``'s) in a fraction of that. Unknown fields of the reply
    are ignored, as in every message; a robot's are refused, as ``Robot``
    refuses them.
    """

    cloud: RecordName
    robots: Annotated[Sequence[RobotRecord], msgspec.Meta(max_length=MAX_ITEMS)]


class _CheckedIdleRobots(IdleRobots, frozen=True):
    cloud: CheckedName
    robots: Annotated[Sequence[CheckedRobotRecord], msgspec.Meta(max_length=MAX_ITEMS)]


_IDLE = msgspec.json.Decoder(IdleRobots)
_CHECKED_IDLE = msgspec.json.Decoder(_CheckedIdleRobots)


def decode_idle_reply(payload: bytes) -> IdleRobots:
    """The reply's robots, or ``ValueError`` saying what is wrong with it.

    The names' rule (printable, one line) is checked only when the reply may
    break it (``may_hold_control_characters``): the check took two thirds of
    the decoding.
    """
    decoder = _CHECKED_IDLE if may_hold_control_characters(payload) else _IDLE
    try:
        return decoder.decode(payload)
    except (msgspec.DecodeError, msgspec.ValidationError) as error:
        raise ValueError(f"an invalid idle reply: {error}") from None


class FleetReply(BaseModel):
    model_config = _WIRE

    cloud: Name
    robots: list[dict[str, Any]]


class Dispatch(BaseModel):
    model_config = _WIRE

    robot: Name
    # A start (robot protocol 1.2) goes through the home like an assign.
    command: Annotated[Assign | Start, Field(discriminator="type")]


class Reservation(BaseModel):
    """Lend robots of the home cloud to a request of the sender; a lease until confirmed.

    ``lease_seconds`` is what the origin asks; the home grants at most its own
    maximum (and its maximum when none is asked).
    """

    model_config = _WIRE

    request_id: Name
    robots: list[Name] = Field(min_length=1, max_length=MAX_ITEMS)
    lease_seconds: float | None = Field(None, gt=0, le=86_400)
    # A reserve only: the commands for these robots, forwarded by the home
    # once all of them are lent (one round trip fewer than a dispatch each).
    dispatch: list[Dispatch] = Field(default_factory=list, max_length=MAX_ITEMS)


class ReserveReply(BaseModel):
    model_config = _WIRE

    taken: list[Name] = Field(default_factory=list, description="robots another request holds")
    error: str | None = None
    acks: list[Ack] = Field(
        default_factory=list, max_length=MAX_ITEMS, description="the robots' acks to ``dispatch``"
    )


class Release(BaseModel):
    model_config = _WIRE

    request_id: Name
    robots: list[Name] | None = Field(None, max_length=MAX_ITEMS)  # None: all of the request
    why: Why | None = None


class Done(BaseModel):
    model_config = _WIRE

    ok: bool = True
    error: str | None = None


class StatusQuery(BaseModel):
    """A home asks the origin about the requests it lends robots to."""

    model_config = _WIRE

    home: Name
    request_ids: list[Name] = Field(min_length=1, max_length=MAX_ITEMS)


class RequestStatus(BaseModel):
    """What the origin says of a request a home holds robots for."""

    model_config = _WIRE

    request_id: Name
    known: bool
    final: bool = False
    robots: list[Name] = Field(default_factory=list, description="its robots now")


class StatusReply(BaseModel):
    model_config = _WIRE

    requests: list[RequestStatus] = Field(default_factory=list, max_length=MAX_ITEMS)


class LoanQuery(BaseModel):
    """The origin asks a home about its loans there; ``told``: notices it has taken in."""

    model_config = _WIRE

    told: list[Name] = Field(default_factory=list, max_length=MAX_ITEMS)


class LoanNotice(BaseModel):
    """A loan the home ended on its own while the origin was away."""

    model_config = _WIRE

    loan: Name
    robot: Name
    request_id: Name
    why: Why


class LoanReply(BaseModel):
    model_config = _WIRE

    cloud: Name
    held: int = Field(0, ge=0, description="robots lent to the asker now")
    ended: list[LoanNotice] = Field(default_factory=list, max_length=MAX_ITEMS)
