"""What the page offers, derived from the robots the IaaS reports.

The IaaS lists each robot's capability names; whether one is sensing or
actuating is read from the robot when the IaaS says (``capability_kinds``, or
capabilities given as MODEL.md's objects) and otherwise from the names the
thesis's robots carry. An unknown name is offered as sensing: the selection
treats both kinds alike, the kind only decides where the form lists it.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from pydantic import BaseModel

# The LEGO NXT-like robots of the thesis's prototype (and of ``robocloud sim``).
KNOWN_KINDS: dict[str, str] = {
    "grabber": "actuating",
    "kicker": "actuating",
    "light": "sensing",
    "ultrasonic": "sensing",
    "sound": "sensing",
    "touch": "sensing",
}
KINDS = ("sensing", "actuating")


class CapabilityOffer(BaseModel):
    """One capability the fleet has: how many robots bring it, how many are idle."""

    name: str
    kind: str
    robots: int
    idle: int


class CloudSummary(BaseModel):
    cloud: str
    robots: int
    idle: int


def capability_kinds(robot: Mapping[str, Any]) -> dict[str, str]:
    """Capability name -> ``sensing`` or ``actuating`` for one robot of ``GET /v1/robots``."""
    given = robot.get("capability_kinds")
    capabilities = robot.get("capabilities") or []
    if isinstance(capabilities, Mapping):
        given = {
            name: (c or {}).get("kind")
            for name, c in capabilities.items()
            if isinstance(c, Mapping)
        } | (given or {})
    kinds: dict[str, str] = {}
    for name in capabilities:
        if not isinstance(name, str):
            continue
        kind = (given or {}).get(name) if isinstance(given, Mapping) else None
        kinds[name] = kind if kind in KINDS else KNOWN_KINDS.get(name, "sensing")
    return kinds


def capability_offers(robots: Iterable[Mapping[str, Any]]) -> list[CapabilityOffer]:
    """Every capability of the fleet, actuating first, then by name."""
    counts: dict[tuple[str, str], list[int]] = {}
    for robot in robots:
        idle = robot.get("status") == "idle"
        for name, kind in capability_kinds(robot).items():
            count = counts.setdefault((kind, name), [0, 0])
            count[0] += 1
            count[1] += int(idle)
    order = sorted(counts, key=lambda key: (key[0] != "actuating", key[1]))
    return [
        CapabilityOffer(
            name=name, kind=kind, robots=counts[kind, name][0], idle=counts[kind, name][1]
        )
        for kind, name in order
    ]


def cloud_summaries(robots: Iterable[Mapping[str, Any]]) -> list[CloudSummary]:
    counts: dict[str, list[int]] = {}
    for robot in robots:
        count = counts.setdefault(str(robot.get("cloud", "?")), [0, 0])
        count[0] += 1
        count[1] += int(robot.get("status") == "idle")
    return [CloudSummary(cloud=c, robots=n, idle=i) for c, (n, i) in sorted(counts.items())]
