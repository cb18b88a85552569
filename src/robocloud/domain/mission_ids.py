"""How a mission and its tasks are named, on the HTTP API and to robots.

A mission's id is ``mis-`` and 12 lower-case base32 characters, like a
request's ``req-...``. Each of its tasks reaches a robot as a request of its
own, ``<mission id>.<n>`` (``n`` from 1, in the order of the mission's
``tasks``; a re-planned task keeps its number): a valid name for the robot
protocol, and one rule, ``holder_of``, tells which mission holds it. Robots
are held, lent and followed for the mission as a whole; their commands name
the task.
"""

from __future__ import annotations

import base64
import re
import secrets

MISSION_ID = re.compile(r"^mis-[a-z2-7]{12}$")
_TASK_REQUEST = re.compile(r"^(mis-[a-z2-7]{12})\.([1-9][0-9]{0,3})$")


def new_mission_id() -> str:
    """``mis-`` and 12 lower-case base32 characters (60 random bits)."""
    return "mis-" + base64.b32encode(secrets.token_bytes(8)).decode("ascii")[:12].lower()


def task_request_id(mission_id: str, number: int) -> str:
    """The request id a robot is told for the mission's task number ``number`` (from 1)."""
    return f"{mission_id}.{number}"


def holder_of(request_id: str) -> str:
    """The id that holds a robot working on ``request_id``: its mission for a mission's
    task (``mis-x.3`` -> ``mis-x``), the request itself otherwise."""
    found = _TASK_REQUEST.fullmatch(request_id)
    return found.group(1) if found else request_id


def task_number(request_id: str) -> int | None:
    """The task number of a mission task's request id, None for anything else."""
    found = _TASK_REQUEST.fullmatch(request_id)
    return int(found.group(2)) if found else None
