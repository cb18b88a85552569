"""Loans kept true between clouds: each side asks the other, every few seconds (``LoanReconciler``).

As a home, this cloud asks each origin it lends to about the requests its
robots work for, and ends the loans the origin no longer uses (the request is
over, or has other robots now), or waited out (the origin unreachable for
``origin_deadline`` seconds while the robot is idle or done). As an origin, it
asks each home it borrowed from which of its loans ended while it was away,
and tells the request (``OriginStatus.loan_ended``). Leases that lapsed end
here too. See ``robocloud.federation.home`` for the loans themselves.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections import defaultdict
from collections.abc import Callable, Iterable
from datetime import datetime
from typing import Protocol

from robocloud.errors import RoboCloudError, Unavailable
from robocloud.federation.home import Home, working_for
from robocloud.federation.messages import MAX_ITEMS, LoanQuery, RequestStatus, StatusQuery
from robocloud.federation.overlay import Overlay
from robocloud.fleet.messages import State
from robocloud.selection.columns import OFFLINE
from robocloud.storage import Loan
from robocloud.storage.rules import utc_now

log = logging.getLogger(__name__)

# A loan this young is not judged by what its origin says: the origin may not
# have recorded the robot yet (it confirms, then starts following it).
_SETTLING = 10.0
# Requests asked about in one status query: the origin reads each from its
# store, and must answer well within the overlay's timeout, or it would pass
# for unreachable.
_STATUS_BATCH = 100


def reconcile_period(origin_deadline: float) -> float:
    """How often ``reconcile`` runs: every 5 s, more often under a short deadline (tests)."""
    return min(5.0, max(0.2, origin_deadline / 4))


class OriginStatus(Protocol):
    """The origin side: what this cloud's service says of, and learns about, its own requests."""

    def loan_ended(self, request_id: str, robot: str, home: str, why: str) -> None:
        """``home`` ended the loan of ``robot`` to the request on its own (this cloud was away).

        Called on a worker thread, at least once per such loan.
        """
        ...


class LoanReconciler:
    def __init__(
        self,
        home: Home,
        overlay: Overlay | None,
        origin: OriginStatus,
        lenders: Callable[[], Iterable[str]],
        *,
        clock: Callable[[], datetime] = utc_now,
        monotonic: Callable[[], float] = time.monotonic,
    ) -> None:
        self.home = home
        self.cloud = home.cloud
        self.store = home.store
        self.link = home.link
        self.origin_deadline = home.origin_deadline
        self.overlay = overlay
        self.origin = origin
        self.lenders = lenders  # the homes this cloud borrowed from (FederationView.lenders)
        self._clock = clock
        self._monotonic = monotonic
        self._started = monotonic()
        self._away_since: dict[str, float] = {}  # origin -> when it first did not answer
        # origin -> (request, robot) of the loans ended here while it was away
        self._ended_away: dict[str, set[tuple[str, str]]] = defaultdict(set)
        self._worked_at: dict[str, float] = {}  # robot -> when last seen working for its loan

    def _forget(self, ended: Iterable[Loan]) -> None:
        ended = list(ended)
        self.home.forget(ended)
        for loan in ended:
            self._worked_at.pop(loan.robot, None)

    def reconcile(self) -> None:
        """Loans whose lease lapsed, origins asked about their loans, this cloud's own loans."""
        self.home.forget(self.store.lapse_loans())
        if self.overlay is None:
            return
        self._ask_origins(self.overlay)
        self._ask_lenders(self.overlay)

    def _ask_origins(self, overlay: Overlay) -> None:
        """Ask each origin about its requests; end the loans it no longer uses, or waited out."""
        now = self._monotonic()
        loans = self.store.loans()
        states: dict[str, State] = {}
        silent: set[str] = set()
        if loans:  # most clouds lend nothing: no need to visit 50,000 robots every 5 s
            states = self.link.states()
            columns = self.link.columns()
            silent = set(columns.id_array[columns.status == OFFLINE].tolist())
        by_origin: dict[str, list[Loan]] = defaultdict(list)
        for loan in loans:
            if loan.robot not in silent and working_for(states.get(loan.robot), loan.request_id):
                self._worked_at[loan.robot] = now
            # Leases not yet dispatched lapse by themselves.
            if loan.expires_at is None:
                by_origin[loan.origin].append(loan)
        for origin in sorted(set(self._away_since) - set(by_origin)):
            self._probe(overlay, origin)
        for origin, loans in by_origin.items():
            request_ids = sorted({loan.request_id for loan in loans})
            try:
                statuses: dict[str, RequestStatus] = {}
                for start in range(0, len(request_ids), _STATUS_BATCH):
                    query = StatusQuery(
                        home=self.cloud, request_ids=request_ids[start : start + _STATUS_BATCH]
                    )
                    for status in overlay.status(origin, query).requests:
                        statuses[status.request_id] = status
            except RoboCloudError:
                self._away(origin, loans, now)
                continue
            self._back(origin)
            self._apply(origin, loans, statuses)

    def _away(self, origin: str, loans: list[Loan], now: float) -> None:
        """The origin did not answer: end the loans idle for longer than the deadline."""
        since = self._away_since.setdefault(origin, now)
        if since == now:
            log.warning("%s does not answer; its %d loans wait for it", origin, len(loans))
        for loan in loans:
            idle_since = max(since, self._worked_at.get(loan.robot, self._started))
            if now - idle_since < self.origin_deadline:
                continue
            why = (
                f"{origin} was unreachable for {self.origin_deadline:g} s "
                f"while robot {loan.robot} was idle or done"
            )
            self.home.stop(loan.robot, loan.request_id)  # harmless when it has no task
            ended = self.store.end_loans(
                origin, loan.request_id, [loan.robot], why, tell_origin=True
            )
            self._forget(ended)
            if ended:
                self._ended_away[origin].add((loan.request_id, loan.robot))
                log.warning(
                    "ended the loan of %s to %s's request %s: %s",
                    loan.robot,
                    origin,
                    loan.request_id,
                    why,
                )

    def _probe(self, overlay: Overlay, origin: str) -> None:
        """An origin away with no loan left here: is it back, to be told of its ended loans?

        Also when it was told already: back, it may have asked for them (its own
        reconciliation) before this one probes; it is back all the same.
        """
        untold = {loan.request_id for loan in self.store.untold_loans(origin)}
        asked = untold or {request_id for request_id, _ in self._ended_away.get(origin, ())}
        if not asked:
            self._away_since.pop(origin, None)
            return
        request_ids = sorted(asked)[:MAX_ITEMS]
        try:
            overlay.status(origin, StatusQuery(home=self.cloud, request_ids=request_ids))
        except RoboCloudError:
            return
        self._back(origin)

    def _back(self, origin: str) -> None:
        if self._away_since.pop(origin, None) is None:
            return
        untold = self.store.untold_loans(origin)
        robots = {loan.robot for loan in untold}
        robots |= {robot for _, robot in self._ended_away.pop(origin, ())}
        if robots:
            log.warning(
                "%s is back; %d of its loans ended while it was away (%s); %s",
                origin,
                len(robots),
                ", ".join(sorted(robots)),
                "it is told when it asks" if untold else "it asked, and was told",
            )
        else:
            log.info("%s is back", origin)

    def _apply(self, origin: str, loans: list[Loan], statuses: dict[str, RequestStatus]) -> None:
        """End the loans the origin no longer uses (not the youngest: it may not know them yet)."""
        settled = self._clock().timestamp() - _SETTLING
        by_request: dict[str, list[str]] = defaultdict(list)
        for loan in loans:
            if loan.updated_at.timestamp() < settled:
                by_request[loan.request_id].append(loan.robot)
        for request_id, robots in by_request.items():
            status = statuses.get(request_id)
            if status is None:
                continue  # not answered: ask again next time
            if not status.known or status.final:
                for robot in robots:
                    self.home.stop(robot, request_id)
                why = f"{origin} says request {request_id} is over"
                self._forget(self.store.end_loans(origin, request_id, robots, why))
                continue
            unwanted = [r for r in robots if r not in status.robots]
            if unwanted:
                why = f"{origin} no longer uses them"
                self._forget(self.store.end_loans(origin, request_id, unwanted, why))

    def _ask_lenders(self, overlay: Overlay) -> None:
        """This cloud as the origin: learn which of its loans the homes ended while it was away."""
        for home in sorted(set(self.lenders()) - {self.cloud}):
            try:
                reply = overlay.loans(home, LoanQuery())
            except RoboCloudError:
                continue
            if not reply.ended:
                continue
            for notice in reply.ended:
                log.warning(
                    "%s ended the loan of %s to request %s: %s",
                    home,
                    notice.robot,
                    notice.request_id,
                    notice.why,
                )
                self.origin.loan_ended(notice.request_id, notice.robot, home, notice.why)
            # Not told back: the home tells again next time; taking it in twice is harmless.
            with contextlib.suppress(RoboCloudError):
                overlay.loans(home, LoanQuery(told=[notice.loan for notice in reply.ended]))

    async def reconcile_forever(self, every: float = 5.0) -> None:
        while True:
            try:
                await asyncio.to_thread(self.reconcile)
            except Unavailable as error:
                log.warning("reconciliation waits for the store: %s", error)
            except Exception:
                log.exception("reconciliation failed")
            await asyncio.sleep(every)
