"""The time budget of one selection: a deadline every stage checks between steps.

A stage that finds its deadline passed stops where it is and hands back what
it has found, saying it was cut; nothing waits on a clock. The service also
runs a selection in a worker process it can kill, but that is the backstop:
this deadline is what normally ends a long search.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Deadline:
    """``at`` is a ``time.perf_counter`` reading; None means no limit."""

    at: float | None = None
    budget_s: float | None = field(default=None, compare=False)

    @classmethod
    def after(cls, seconds: float | None) -> Deadline:
        if seconds is None:
            return cls()
        return cls(time.perf_counter() + seconds, seconds)

    def expired(self) -> bool:
        return self.at is not None and time.perf_counter() >= self.at

    def remaining(self) -> float:
        """Seconds left, never negative; infinite without a limit."""
        if self.at is None:
            return math.inf
        return max(0.0, self.at - time.perf_counter())


NO_DEADLINE = Deadline()
