"""Background life of a fleet: robots that robocloud does not control come and go.

The wildfire scenario draws a fleet in exact status shares (25% idle, 30%
busy, 15% reserved, 15% charging, 15% offline). Left alone those robots
would all end up idle; the churn keeps the shares stable (choice):

- an idle robot starts an activity after an exponential wait of mean
  ``idle_mean`` seconds: busy, reserved, charging or offline with
  probabilities 0.4, 0.2, 0.2, 0.2; it charges at once when its battery is
  below ``low_battery``;
- busy, reserved and offline last an exponential time of mean
  ``activity_mean`` seconds; busy drains ``busy_drain`` percent a second
  (driving and working for someone else);
- charging adds ``charge_rate`` percent a second until the battery is full.

With the defaults (100 s, 300 s, 0.06 %/s, 0.1 %/s) a 500-robot fleet run for
six simulated hours settles at idle 24%, busy 29%, reserved 15%, charging 17%,
offline 14%, mean battery 74%, idle with 70% or more 18%. Robots on an IaaS
task are never touched. All times are simulated seconds.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from robocloud.domain import RobotStatus
from robocloud.sim.robot import Background, SimRobot

ACTIVITIES: tuple[tuple[RobotStatus, float], ...] = (
    ("busy", 0.4),
    ("reserved", 0.2),
    ("charging", 0.2),
    ("offline", 0.2),
)


@dataclass(frozen=True)
class ChurnRates:
    idle_mean: float = 100.0
    activity_mean: float = 300.0
    busy_drain: float = 0.06
    charge_rate: float = 0.1
    low_battery: float = 20.0


class Churn:
    """Starts background activities; ``enabled=False`` keeps every status as drawn.

    ``recharge_below``, without churn: an idle robot whose battery is below
    that many percent goes charging (at ``charge_rate``) until full, as a
    robot that docks itself would, and does nothing else on its own. Without
    it a fleet under a long stream of tasks runs dry (benchmarks/results/design-notes.md,
    recharge).
    """

    def __init__(
        self,
        rng: np.random.Generator,
        enabled: bool = True,
        rates: ChurnRates | None = None,
        recharge_below: float | None = None,
    ) -> None:
        self._rng = rng
        self.enabled = enabled
        self.rates = rates or ChurnRates()
        self.recharge_below = recharge_below
        self._statuses = [status for status, _ in ACTIVITIES]
        self._weights = np.array([weight for _, weight in ACTIVITIES])

    def adopt(self, robot: SimRobot) -> None:
        """Give a robot drawn busy, reserved, charging or offline its activity."""
        if robot.status == "idle":
            return
        robot.start_background(self.activity(robot, robot.status))
        robot.dirty = False

    def activity(self, robot: SimRobot, status: RobotStatus) -> Background:
        if not self.enabled:
            return Background(status, math.inf)
        if status == "charging":
            return self._charging(robot)
        remaining = float(self._rng.exponential(self.rates.activity_mean))
        drain = self.rates.busy_drain if status == "busy" else 0.0
        return Background(status, remaining, -drain)

    def _charging(self, robot: SimRobot) -> Background:
        rate = self.rates.charge_rate
        return Background("charging", (100.0 - robot.battery) / rate, rate)

    def step(self, robots: Sequence[SimRobot], dt: float) -> None:
        """Start activities on idle robots for ``dt`` simulated seconds."""
        if dt <= 0.0:
            return
        if not self.enabled:
            if self.recharge_below is not None:
                for robot in robots:
                    if robot.battery < self.recharge_below and robot.available and not robot.dead:
                        robot.start_background(self._charging(robot))
            return
        idle = [robot for robot in robots if robot.available and not robot.dead]
        if not idle:
            return
        start = self._rng.random(len(idle)) < -math.expm1(-dt / self.rates.idle_mean)
        picks = self._rng.choice(len(self._statuses), size=len(idle), p=self._weights)
        for robot, go, pick in zip(idle, start.tolist(), picks.tolist(), strict=True):
            if robot.battery < self.rates.low_battery:
                robot.start_background(self.activity(robot, "charging"))
            elif go:
                robot.start_background(self.activity(robot, self._statuses[pick]))
