"""The seam: what the IaaS asks of its request store.

Two implementations: ``SqlRequestStore`` (SQLite or PostgreSQL) and
``MemoryRequestStore`` (for fast tests). Every method is synchronous and
thread-safe, and every change is committed before the method returns.
"""

from __future__ import annotations

import builtins
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from robocloud.errors import Unavailable
from robocloud.storage.records import Loan, MissionRow, RequestRecord


class StoreUnavailable(Unavailable):
    """The database cannot be reached or opened; the sentence names it (without password)."""

    def __init__(self, message: str, url: str | None = None) -> None:
        super().__init__(message)
        self.url = url


class RequestStore(Protocol):
    """Requests, their state history, robot reservations and loans of one cloud.

    A robot has at most one holder at a time: a request of this cloud (a
    reservation) or a loan to a request of another cloud. ``reserve``,
    ``replace`` and ``lend`` all refuse a robot another holder has, in the
    same transaction that takes it.

    Errors: ``InvalidInput`` (a bad argument), ``NotFound`` (no such request),
    ``Conflict`` (a move the request's state does not allow), ``StoreUnavailable``.

    ``local_reads``: reads are local (a file or memory) and take well under a
    millisecond, so a caller on an event loop may make them in place rather
    than on a worker thread, whose hand-offs cost more than the read.
    """

    local_reads: bool

    def create_request(
        self,
        application: str,
        task: dict[str, Any],
        label: str | None = None,
        idempotency_key: str | None = None,
    ) -> tuple[RequestRecord, bool]:
        """A new request in state ``received``, and True.

        If ``application`` already used ``idempotency_key``, its request as it
        is now, and False; nothing is created then, even under a race.
        """
        ...

    def get(self, request_id: str, application: str | None = None) -> RequestRecord | None:
        """The request, or None; None also when ``application`` is given and not its owner."""
        ...

    def by_idempotency_key(self, application: str, idempotency_key: str) -> RequestRecord | None:
        """The request ``application`` created with ``idempotency_key``, or None."""
        ...

    def list(
        self,
        application: str,
        state: str | None = None,
        limit: int = 50,
        before: str | None = None,
    ) -> tuple[builtins.list[RequestRecord], str | None]:
        """One page of ``application``'s requests, newest first, and the next page's cursor.

        ``before`` is the cursor returned with the previous page (the id of its
        last request); the cursor is None on the last page.
        """
        ...

    def transition(
        self,
        request_id: str,
        new_state: str,
        reason: str | None = None,
        detail: str | None = None,
        selection: dict[str, Any] | None = None,
    ) -> RequestRecord:
        """Move the request to ``new_state`` if ``robocloud.domain.can_move`` allows it.

        ``reason`` and ``selection`` replace the stored ones when given. Moving
        to a final state releases every reservation of the request, in the same
        transaction. Raises ``Conflict`` for a refused move.
        """
        ...

    def add_event(self, request_id: str, detail: str) -> RequestRecord:
        """Add a history entry that does not change the state."""
        ...

    def set_selection(self, request_id: str, selection: dict[str, Any]) -> RequestRecord:
        """Replace the request's selection (opaque JSON)."""
        ...

    def active(self) -> builtins.list[RequestRecord]:
        """Every request not in a final state, oldest first (to resume them on restart)."""
        ...

    def reserve(
        self,
        request_id: str,
        robot_ids: Sequence[str],
        lease_seconds: float | None = None,
    ) -> builtins.list[str]:
        """Reserve the robots for the request, all or nothing.

        Returns [] on success, or the robots already held by another request
        (in the order given), and then nothing is reserved. With
        ``lease_seconds`` the reservation is a lease that lapses unless
        confirmed; a lapsed lease counts as free. Robots the request already
        holds stay held (a lease is extended, never shortened; a firm one stays
        firm). Raises ``Conflict`` if the request is in a final state.
        """
        ...

    def confirm(self, request_id: str, robot_ids: Sequence[str]) -> builtins.list[str]:
        """Make the request's hold on the robots firm (no expiry).

        The same as ``reserve`` without a lease: a robot whose lease lapsed is
        taken again if nobody else took it; returns the robots held by another
        request, and then nothing changes.
        """
        ...

    def release(self, request_id: str, robot_ids: Sequence[str] | None = None) -> None:
        """Release the request's hold on these robots (None: on all of its robots)."""
        ...

    def replace(
        self,
        request_id: str,
        old_robot: str,
        new_robot: str,
        lease_seconds: float | None = None,
    ) -> builtins.list[str]:
        """Reserve ``new_robot`` and release ``old_robot`` in one transaction.

        Returns [] on success, or ``[new_robot]`` when another request holds it
        (and then ``old_robot`` stays reserved).
        """
        ...

    def reservations(self, request_id: str | None = None) -> dict[str, str]:
        """Robot id -> holder of every unexpired hold (of one request if given).

        The holder is a request id, or for a robot lent to another cloud the
        loan's id (``loan-...``), which is never a request id.
        """
        ...

    # loans: robots of this cloud lent to other clouds' requests (robocloud.federation.home)

    def lend(
        self,
        origin: str,
        request_id: str,
        robot_ids: Sequence[str],
        lease_seconds: float,
    ) -> builtins.list[str]:
        """Lease the robots to ``origin``'s request ``request_id``, all or nothing.

        Returns [] on success, or the robots another holder has (in the order
        given), and then nothing changes. A robot already lent to this origin
        request stays lent: its lease is extended, never shortened; a firm
        loan stays firm. A lapsed lease counts as free.
        """
        ...

    def confirm_loans(
        self, origin: str, request_id: str, robot_ids: Sequence[str]
    ) -> builtins.list[str]:
        """Make the loans of the robots to this origin request firm (those already firm stay).

        Returns [] on success, or the robots with no live loan to it (never
        leased, lapsed, released or lent to another), and then nothing changes:
        a confirm never takes a robot.
        """
        ...

    def end_loans(
        self,
        origin: str,
        request_id: str,
        robot_ids: Sequence[str] | None,
        why: str,
        *,
        tell_origin: bool = False,
    ) -> builtins.list[Loan]:
        """Release the loans of the robots (None: all) to this origin request.

        Returns the loans ended (those already released are left alone).
        ``tell_origin``: the home ends them on its own, and the origin is to be
        told when it asks (``untold_loans``).
        """
        ...

    def lapse_loans(self) -> builtins.list[Loan]:
        """Release every loan whose lease lapsed; returns them."""
        ...

    def loan_of(self, robot_id: str) -> Loan | None:
        """The live loan holding the robot now (with its history), or None."""
        ...

    def loans(
        self, origin: str | None = None, request_id: str | None = None
    ) -> builtins.list[Loan]:
        """Every live loan (of one origin, one origin request), oldest first (then by robot).

        Without their history, which ``loan_of`` gives.
        """
        ...

    def count_loans(self, origin: str) -> int:
        """How many live loans ``origin`` holds: ``len(loans(origin))`` without reading them
        (a home counts them at each reservation)."""
        ...

    def untold_loans(self, origin: str) -> builtins.list[Loan]:
        """The loans of ``origin`` the home ended on its own and has not told it about."""
        ...

    def told(self, origin: str, loan_ids: Sequence[str]) -> builtins.list[Loan]:
        """``origin`` learnt that these of its loans ended; returns those marked."""
        ...

    def save_mission(self, row: MissionRow) -> MissionRow:
        """Store a mission, new or its latest JSON. A new one whose Idempotency-Key the
        application used already is not stored: the one it was used for is returned."""
        ...

    def mission(self, mission_id: str, application: str | None = None) -> MissionRow | None:
        ...

    def mission_by_key(self, application: str, idempotency_key: str) -> MissionRow | None:
        ...

    def missions(
        self, application: str, state: str | None, limit: int, before: str | None
    ) -> tuple[builtins.list[MissionRow], str | None]:
        """The application's missions, newest first, after the cursor ``before``;
        and the next cursor (None on the last page)."""
        ...

    def unfinished_missions(self) -> builtins.list[MissionRow]:
        """Every mission not in a final state (a restarted IaaS ends them)."""
        ...

    def together(self, calls: Sequence[Callable[[], Any]]) -> builtins.list[Outcome]:
        """Run ``calls`` (calls of this store's methods) in turn; each one's answer or error.

        Each call is all or nothing, as when made alone, and sees the calls
        before it. A store may commit them together: on SQLite they share one
        transaction (a savepoint each), which is what makes writes cheap
        under load. Nothing of a call is stored that did not answer.
        """
        ...

    def close(self) -> None:
        """Release the store's connections; the store is not used afterwards."""
        ...


@dataclass(frozen=True)
class Outcome:
    """What one call of ``RequestStore.together`` gave: its answer, or the error it raised."""

    value: Any = None
    error: Exception | None = None

    def get(self) -> Any:
        if self.error is not None:
            raise self.error
        return self.value


def outcome_of(call: Callable[[], Any]) -> Outcome:
    """Make one call: its answer or its error (an Exception; anything else goes through)."""
    try:
        return Outcome(call())
    except Exception as error:
        return Outcome(error=error)
