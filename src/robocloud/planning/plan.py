"""What a planner returns (``Plan``) and which method made it (``Method``).

Apart from ``solve.py`` so that the child process's protocol (``worker.py``)
and the solvers share the shape without importing each other.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from robocloud.planning.schedule import Schedule

Method = Literal["exact", "anytime"]


@dataclass(frozen=True)
class Plan:
    schedule: Schedule | None
    lower_bound: float | None
    optimal: bool
    method: Method
    elapsed_s: float
    reason: str | None  # why there is no plan

    @property
    def gap(self) -> float | None:
        """(makespan - lower bound) / makespan: how much shorter a plan could be, at most."""
        if self.schedule is None or self.lower_bound is None:
            return None
        if self.schedule.makespan <= 0:
            return 0.0
        return max(0.0, (self.schedule.makespan - self.lower_bound) / self.schedule.makespan)
