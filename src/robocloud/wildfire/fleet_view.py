"""Which capabilities are sensing and which actuating, read from the robots the IaaS reports.

The IaaS lists each robot's capability names; whether one is sensing or
actuating is read from the robot when the IaaS says (``capability_kinds``, or
capabilities given as docs/model.md's objects) and otherwise from the names the
thesis's robots carry. An unknown name is offered as sensing: the selection
treats both kinds alike, the kind only decides where the form lists it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

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
MAX_CAPABILITIES = 64  # a robot claiming more is cut short, not trusted to fill the page


def capability_kinds(robot: Mapping[str, Any]) -> dict[str, str]:
    """Capability name -> ``sensing`` or ``actuating`` for one robot of ``GET /v1/robots``."""
    stated = robot.get("capability_kinds")
    given: dict[Any, Any] = dict(stated) if isinstance(stated, Mapping) else {}
    capabilities = robot.get("capabilities") or []
    if isinstance(capabilities, Mapping):
        given = {
            name: c.get("kind") for name, c in capabilities.items() if isinstance(c, Mapping)
        } | given
    if not isinstance(capabilities, Mapping | list):
        return {}
    kinds: dict[str, str] = {}
    for name in list(capabilities)[:MAX_CAPABILITIES]:
        if not isinstance(name, str) or not name or len(name) > 64:
            continue
        kind = given.get(name)
        kinds[name] = kind if kind in KINDS else KNOWN_KINDS.get(name, "sensing")
    return kinds
