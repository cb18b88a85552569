"""Fault injection: the simulator's control messages, for tests and by hand.

A query on ``robocloud/<cloud>/sim/control`` whose payload is::

    {"fault": "silent", "robot": "a-0001"}    the robot stops publishing and answering
    {"fault": "recover", "robot": "a-0001"}   it publishes and answers again
    {"fault": "battery", "robot": "a-0001"}   its battery dies now: offline, its task failed

is answered with an Ack (``robocloud.fleet.messages``) naming the robot;
ok is false, with a sentence, for a robot the simulator does not have.
A silent robot keeps moving and working; only its radio is off.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict

from robocloud.domain.robot import Name

FaultName = Literal["silent", "recover", "battery"]


class Fault(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    fault: FaultName
    robot: Name
