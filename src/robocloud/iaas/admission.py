"""Load shedding: whether a new request is taken now, or refused with 503 (``Admission``).

Accepting what the cloud cannot decide in time makes every request late:
robots stay held by requests the IaaS has not caught up with, and later ones
are rejected for want of them, seconds after their 202 (measured at 200
requests/s on 1,000 robots: 1,510 of 2,000 accepted requests rejected so, the
median dispatched after 2.9 s). So a new request is refused while
``max_waiting`` requests wait for their robots, or while at least
``BUSY_MIN`` wait and the oldest has waited ``busy_after`` seconds: one slow
selection alone never refuses any.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from robocloud.errors import Busy
from robocloud.iaas.metrics import IaasMetrics

# A cloud is busy (new requests refused) only when at least this many requests
# wait and the oldest has waited too long: one slow selection alone is not busy.
BUSY_MIN = 8


class Admission:
    """The requests not decided yet (received or selecting), oldest first, and the rule."""

    def __init__(
        self,
        max_waiting: int,
        busy_after: float,
        metrics: IaasMetrics,
        mono: Callable[[], float] = time.monotonic,
    ) -> None:
        self.max_waiting = max_waiting
        self.busy_after = busy_after
        self.metrics = metrics
        self.mono = mono
        self._waiting: dict[str, float] = {}  # request -> when it came (mono)

    def waits(self, request_id: str, since: float | None = None) -> None:
        """The request waits for its robots (new, or resumed after a restart)."""
        self._waiting[request_id] = self.mono() if since is None else since

    def decided(self, request_id: str) -> None:
        """The request no longer waits: dispatched, rejected, failed or canceled."""
        self._waiting.pop(request_id, None)

    def admit(self, now: float | None = None) -> None:
        """Raise ``Busy`` (counted in the metrics) when a new request is refused now."""
        refusal = self.busy(now)
        if refusal is not None:
            self.metrics.refused.inc()
            raise refusal

    def busy(self, now: float | None = None) -> Busy | None:
        """Why a new request is refused now (503), or None."""
        waiting = len(self._waiting)
        if waiting < BUSY_MIN and waiting < self.max_waiting:
            return None
        if waiting >= self.max_waiting:
            are = "request is waiting for its" if waiting == 1 else "requests are waiting for their"
            return Busy(
                f"this cloud is busy: {waiting} {are} robots, its limit; "
                "try again after Retry-After seconds."
            )
        now = self.mono() if now is None else now
        waited = now - next(iter(self._waiting.values()))
        if waited > self.busy_after:
            return Busy(
                f"this cloud is busy: {waiting} requests are waiting for their robots, the "
                f"oldest for {waited:.2f} s (over {self.busy_after:g} s); try again "
                "after Retry-After seconds."
            )
        return None
