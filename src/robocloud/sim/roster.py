"""The robots of one simulated cloud, drawn as the wildfire scenario draws them.

Same forest, same LEGO NXT-like robots, same status shares as
``robocloud.sim.scenario``; the ids carry the cloud's letter (``b-0001`` for
``cloud-b``) and each robot its ``kind`` (``tribot`` or ``base``). The fleet
depends on the seed and on the cloud's name, so two clouds started with the
same seed do not get the same robots.
"""

from __future__ import annotations

import re
import zlib
from typing import Any

from robocloud.errors import InvalidInput
from robocloud.fleet import keys
from robocloud.sim.robot import KIND_BY_ACTUATOR
from robocloud.sim.scenario import wildfire_robots

_CLOUD_LETTER = re.compile(r"^cloud-([a-z])$")


def cloud_letter(cloud: str) -> str:
    """``b`` for ``cloud-b``; otherwise the first letter or digit of the name, lower case."""
    match = _CLOUD_LETTER.match(cloud)
    if match:
        return match.group(1)
    for ch in cloud:
        if ch.isascii() and ch.isalnum():
            return ch.lower()
    raise InvalidInput(f"cloud {cloud!r} has no letter to name its robots by.", field="cloud")


def cloud_robots(cloud: str, robots: int, seed: int = 0) -> list[dict[str, Any]]:
    """``robots`` robots of ``cloud`` as JSON dicts: a docs/model.md robot plus ``kind``."""
    keys.check_chunk(cloud, "cloud")
    if seed < 0:
        raise InvalidInput(f"seed must be 0 or more, not {seed}.", field="seed")
    letter = cloud_letter(cloud)
    # One stream per (seed, cloud): crc32 is stable across runs, unlike hash().
    drawn = wildfire_robots(robots, clouds=1, seed=seed * 2**32 + zlib.crc32(cloud.encode()))
    fleet: list[dict[str, Any]] = []
    for robot in drawn:
        number = robot["id"].split("-", 1)[1]
        actuators = robot["capabilities"]
        kind = next(k for actuator, k in KIND_BY_ACTUATOR.items() if actuator in actuators)
        fleet.append({**robot, "id": f"{letter}-{number}", "cloud": cloud, "kind": kind})
    return fleet
