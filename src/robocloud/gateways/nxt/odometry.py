"""Where a differential-drive brick is, from its drive motors' tachometers (dead reckoning).

Each wheel's motor counts degrees (GETOUTPUTSTATE's rotation count). Between
two readings the wheels covered ``dl`` and ``dr`` metres (degrees / 360 x
pi x wheel diameter); the brick moved ``(dl + dr) / 2`` along its heading
turned by half of ``(dr - dl) / track width``, and turned by all of it.

Error: exact for the two motions the gateway drives (turning in place,
driving straight) when wheels neither slip nor differ; in practice the
tachometer's 1 degree (0.5 mm of a 56 mm wheel) is nothing beside slip,
wheel diameter (about 1 % between tyres) and the effective track width (a
few mm of 112 mm: 3 % of every turn). Expect a few centimetres per metre and
a heading off by degrees after a few turns; the error only grows, since
nothing here sees the world. The stand-in brick's wheels do not slip, so
against it the gateway's pose is exact to the degree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass
class Odometry:
    x: float
    y: float
    heading: float  # radians, 0 along +x, counter-clockwise
    wheel_diameter: float
    track_width: float

    def metres(self, degrees: float) -> float:
        return degrees / 360.0 * math.pi * self.wheel_diameter

    def degrees(self, metres: float) -> float:
        return metres / (math.pi * self.wheel_diameter) * 360.0

    def advance(self, left_degrees: float, right_degrees: float) -> None:
        dl, dr = self.metres(left_degrees), self.metres(right_degrees)
        turn = (dr - dl) / self.track_width
        ahead = (dl + dr) / 2.0
        middle = self.heading + turn / 2.0
        self.x += ahead * math.cos(middle)
        self.y += ahead * math.sin(middle)
        self.heading = math.remainder(self.heading + turn, math.tau)

    def turn_degrees(self, angle: float) -> float:
        """Degrees each wheel turns (opposite ways) to turn the brick by ``angle`` radians."""
        return self.degrees(abs(angle) * self.track_width / 2.0)
