"""``SqlLoans``: robots of this cloud lent to other clouds' requests, in SQL.

The loan half of ``SqlRequestStore`` (the home side of federation,
``robocloud.federation.home``, calls it through the store). Loans hold their
robots in the ``reservations`` table, as requests do, so a robot lent to
another cloud is never reserved by a request of this one, nor the reverse:
the primary key decides a race, and ``lend`` runs again on a unique
violation (``Database.run``) and reports the robot as taken. ``loans`` keeps
every loan, ended ones too, with its history in ``loan_history``.
"""

from __future__ import annotations

import builtins
from collections.abc import Sequence
from datetime import datetime
from typing import Any

from sqlalchemy import Connection, Row, func, insert, select, update

from robocloud.storage import rules
from robocloud.storage.engine import Database
from robocloud.storage.records import Loan, StateChange, new_loan_id
from robocloud.storage.schema import loan_history, loans, reservations
from robocloud.storage.sql_holds import add_loan_history, drop_lapsed, end_loans, live_holds
from robocloud.storage.statements import unexpired

ACTIVE_LOANS = ("leased", "firm")  # as a list, not != released: the state index serves it


class SqlLoans:
    """The ``RequestStore`` methods of loans, on ``db``."""

    def __init__(self, db: Database, clock: rules.StoreClock) -> None:
        self._db = db
        self._clock = clock

    def lend(
        self,
        origin: str,
        request_id: str,
        robot_ids: Sequence[str],
        lease_seconds: float,
    ) -> builtins.list[str]:
        rules.check_name(origin, "origin", "origin")
        rules.check_name(request_id, "request_id", "request_id")
        robots = rules.check_robots(robot_ids)
        rules.check_lease(lease_seconds, self._clock())  # check it before any work

        def work(conn: Connection) -> builtins.list[str]:
            now = self._clock()
            expires_at = rules.check_lease(lease_seconds, now)
            held = {
                row.robot_id: row
                for row in live_holds(conn, robots, now, sqlite=self._db.sqlite)
            }
            mine: dict[str, Any] = {}
            if any(row.loan_id is not None for row in held.values()):
                mine = self._lent(conn, origin, request_id, robots, now)
            taken = [
                r for r in robots if r in held and (r not in mine or held[r].loan_id != mine[r].id)
            ]
            if taken:
                return taken
            new = sorted(r for r in robots if r not in held)  # one order: no deadlocks
            if new:
                ids = {r: new_loan_id() for r in new}
                # Plain parameters (one statement, compiled once and cached), not
                # a multi-row VALUES: loan ids are new, so no race is lost here.
                conn.execute(
                    insert(loans),
                    [
                        {
                            "id": ids[r],
                            "robot_id": r,
                            "origin": origin,
                            "request_id": request_id,
                            "state": "leased",
                            "expires_at": expires_at,
                            "tell_origin": False,
                            "created_at": now,
                            "updated_at": now,
                        }
                        for r in new
                    ],
                )
                add_loan_history(
                    conn, [(ids[r], "leased", f"lent to {origin}") for r in new], now
                )
                holds = [
                    {"robot_id": r, "loan_id": ids[r], "expires_at": expires_at, "created_at": now}
                    for r in new
                ]
                # The robots' race is decided here (the primary key): one multi-row
                # INSERT for several, as a request's reservation does; one robot
                # needs no more.
                conn.execute(
                    insert(reservations).values(holds) if len(holds) > 1 else insert(reservations),
                    holds[0] if len(holds) == 1 else None,
                )
            longer = [
                mine[r].id
                for r in robots
                if r in mine and mine[r].expires_at is not None and mine[r].expires_at < expires_at
            ]
            if longer:
                conn.execute(
                    update(loans)
                    .where(loans.c.id.in_(longer))
                    .values(expires_at=expires_at, updated_at=now)
                )
                conn.execute(
                    update(reservations)
                    .where(reservations.c.loan_id.in_(longer))
                    .values(expires_at=expires_at)
                )
            return []

        return self._db.run(work, write=True, retry_integrity=True)

    def confirm_loans(
        self, origin: str, request_id: str, robot_ids: Sequence[str]
    ) -> builtins.list[str]:
        robots = rules.check_robots(robot_ids)

        def work(conn: Connection) -> builtins.list[str]:
            now = self._clock()
            mine = self._lent(conn, origin, request_id, robots, now)
            lost = [r for r in robots if r not in mine]
            if lost:
                return lost
            self._make_firm(conn, [row for row in mine.values()], now, "confirmed")
            return []

        return self._db.run(work, write=True)

    def end_loans(
        self,
        origin: str,
        request_id: str,
        robot_ids: Sequence[str] | None,
        why: str,
        *,
        tell_origin: bool = False,
    ) -> builtins.list[Loan]:
        robots = None if robot_ids is None else rules.check_robots(robot_ids)
        rules.check_why(why)

        def work(conn: Connection) -> builtins.list[Loan]:
            now = self._clock()
            query = (
                select(loans.c.id)
                .where(
                    loans.c.origin == origin,
                    loans.c.request_id == request_id,
                    loans.c.state.in_(ACTIVE_LOANS),
                )
                .order_by(loans.c.id)
                .with_for_update()
            )
            if robots is not None:
                query = query.where(loans.c.robot_id.in_(robots))
            ids = [row.id for row in conn.execute(query)]
            end_loans(conn, ids, now, why, tell_origin)
            return self._loans_by_id(conn, ids, history=False)

        return self._db.run(work, write=True)

    def lapse_loans(self) -> builtins.list[Loan]:
        def work(conn: Connection) -> builtins.list[Loan]:
            now = self._clock()
            lapsed = conn.execute(
                select(reservations.c.robot_id, reservations.c.loan_id).where(
                    reservations.c.loan_id.is_not(None), reservations.c.expires_at < now
                )
            ).all()
            ids = drop_lapsed(conn, lapsed, now)
            return self._loans_by_id(conn, ids, history=False)

        return self._db.run(work, write=True)

    def loan_of(self, robot_id: str) -> Loan | None:
        def work(conn: Connection) -> Loan | None:
            loan_id = conn.execute(
                select(reservations.c.loan_id).where(
                    reservations.c.robot_id == robot_id,
                    reservations.c.loan_id.is_not(None),
                    unexpired(reservations.c.expires_at, self._clock()),
                )
            ).scalar_one_or_none()
            if loan_id is None:
                return None
            return self._loans_by_id(conn, [loan_id], history=True)[0]

        return self._db.run(work, write=False)

    def loans(
        self, origin: str | None = None, request_id: str | None = None
    ) -> builtins.list[Loan]:
        def work(conn: Connection) -> builtins.list[Loan]:
            query = select(loans).where(
                loans.c.state.in_(ACTIVE_LOANS), unexpired(loans.c.expires_at, self._clock())
            )
            if origin is not None:
                query = query.where(loans.c.origin == origin)
            if request_id is not None:
                query = query.where(loans.c.request_id == request_id)
            rows = conn.execute(
                query.order_by(loans.c.created_at, loans.c.robot_id, loans.c.id)
            ).all()
            return [_loan(row) for row in rows]

        return self._db.run(work, write=False)

    def count_loans(self, origin: str) -> int:
        def work(conn: Connection) -> int:
            count: int = conn.execute(
                select(func.count())
                .select_from(loans)
                .where(
                    loans.c.origin == origin,
                    loans.c.state.in_(ACTIVE_LOANS),
                    unexpired(loans.c.expires_at, self._clock()),
                )
            ).scalar_one()
            return count

        return self._db.run(work, write=False)

    def untold_loans(self, origin: str) -> builtins.list[Loan]:
        def work(conn: Connection) -> builtins.list[Loan]:
            rows = conn.execute(
                select(loans)
                .where(loans.c.origin == origin, loans.c.tell_origin.is_(True))
                .order_by(loans.c.updated_at, loans.c.id)
            ).all()
            return [_loan(row) for row in rows]

        return self._db.run(work, write=False)

    def told(self, origin: str, loan_ids: Sequence[str]) -> builtins.list[Loan]:
        ids = rules.check_names(loan_ids, "a loan id", "loan_ids")

        def work(conn: Connection) -> builtins.list[Loan]:
            now = self._clock()
            marked = [
                row.id
                for row in conn.execute(
                    select(loans.c.id)
                    .where(
                        loans.c.origin == origin,
                        loans.c.id.in_(ids),
                        loans.c.tell_origin.is_(True),
                    )
                    .order_by(loans.c.id)
                    .with_for_update()
                )
            ]
            if marked:
                conn.execute(
                    update(loans)
                    .where(loans.c.id.in_(marked))
                    .values(tell_origin=False, updated_at=now)
                )
                add_loan_history(
                    conn,
                    [(i, "released", f"{origin} was told that the loan ended") for i in marked],
                    now,
                )
            return self._loans_by_id(conn, marked, history=False)

        return self._db.run(work, write=True)

    # rows

    def _lent(
        self,
        conn: Connection,
        origin: str,
        request_id: str,
        robots: builtins.list[str],
        now: datetime,
    ) -> dict[str, Any]:
        """The live loans (not released, lease not lapsed) of ``robots`` to the origin request.

        Locked until the transaction ends (PostgreSQL).
        """
        rows = conn.execute(
            select(loans)
            .where(
                loans.c.origin == origin,
                loans.c.request_id == request_id,
                loans.c.robot_id.in_(robots),
                loans.c.state.in_(ACTIVE_LOANS),
                unexpired(loans.c.expires_at, now),
            )
            .order_by(loans.c.id)
            .with_for_update()
        ).all()
        return {row.robot_id: row for row in rows}

    def _make_firm(self, conn: Connection, rows: Sequence[Any], now: datetime, why: str) -> None:
        """Make these loans (rows of ``_lent``) firm: their robots no longer lapse."""
        ids = [row.id for row in rows if row.state == "leased"]
        if not ids:
            return
        conn.execute(
            update(loans)
            .where(loans.c.id.in_(ids))
            .values(state="firm", expires_at=None, updated_at=now)
        )
        conn.execute(
            update(reservations).where(reservations.c.loan_id.in_(ids)).values(expires_at=None)
        )
        add_loan_history(conn, [(i, "firm", why) for i in ids], now)

    def _loans_by_id(
        self, conn: Connection, ids: builtins.list[str], history: bool
    ) -> builtins.list[Loan]:
        if not ids:
            return []
        rows = conn.execute(select(loans).where(loans.c.id.in_(ids)).order_by(loans.c.id)).all()
        lines: dict[str, builtins.list[StateChange]] = {row.id: [] for row in rows}
        if history:
            for line in conn.execute(
                select(loan_history)
                .where(loan_history.c.loan_id.in_(ids))
                .order_by(loan_history.c.loan_id, loan_history.c.id)
            ):
                previous = lines[line.loan_id][-1].state if lines[line.loan_id] else None
                lines[line.loan_id].append(
                    StateChange(
                        line.state,
                        line.at,
                        line.detail,
                        "event" if line.state == previous else "state",
                    )
                )
        by_id = {row.id: _loan(row, tuple(lines[row.id])) for row in rows}
        return [by_id[i] for i in ids if i in by_id]


def _loan(row: Row[Any], history: tuple[StateChange, ...] = ()) -> Loan:
    """A row of ``loans`` and its history."""
    return Loan(
        id=row.id,
        robot=row.robot_id,
        origin=row.origin,
        request_id=row.request_id,
        state=row.state,
        expires_at=row.expires_at,
        created_at=row.created_at,
        updated_at=row.updated_at,
        reason=row.reason,
        tell_origin=bool(row.tell_origin),
        history=history,
    )
