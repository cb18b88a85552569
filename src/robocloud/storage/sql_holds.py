"""The robots' holds, shared by requests and loans: who holds a robot now, and lapses.

A row of ``reservations`` is held by a request of this cloud or by a loan to
another cloud's request. Reserving for a request (``sql_requests``) and
lending (``sql_loans``) both start by reading the holds on their robots;
a hold whose lease lapsed is free, whoever held it, and a lapsed loan ends
(``end_loans``). Both halves call these functions, so they sit below both.

Functions of an open transaction (``conn``); the caller's store took it.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import Any

from sqlalchemy import Connection, delete, insert, update

from robocloud.storage import rules, statements
from robocloud.storage.schema import loan_history, loans, reservations
from robocloud.storage.sqlite_rows import SqliteRows


def live_holds(
    conn: Connection, robots: list[str], now: datetime, *, sqlite: bool
) -> list[Any]:
    """The holds on ``robots`` that have not lapsed; lapsed ones are deleted (free).

    A lapsed lease is free, whoever held it; a lapsed loan ends.
    """
    rows: Sequence[Any] = (
        SqliteRows(conn).holds_of(robots)
        if sqlite
        else conn.execute(statements.HOLDS_OF, {"robots": robots}).all()
    )
    lapsed = [row for row in rows if rules.is_expired(row.expires_at, now)]
    if lapsed:
        drop_lapsed(conn, lapsed, now)
    return [row for row in rows if not rules.is_expired(row.expires_at, now)]


def drop_lapsed(conn: Connection, lapsed: Sequence[Any], now: datetime) -> list[str]:
    """Delete lapsed holds (rows with robot_id and loan_id); end their loans."""
    if not lapsed:
        return []
    conn.execute(
        delete(reservations).where(
            reservations.c.robot_id.in_([row.robot_id for row in lapsed]),
            reservations.c.expires_at < now,
        )
    )
    ended = [row.loan_id for row in lapsed if row.loan_id is not None]
    end_loans(conn, ended, now, "the lease lapsed", False)
    return ended


def end_loans(
    conn: Connection,
    ids: list[str],
    now: datetime,
    why: str,
    tell_origin: bool,
) -> None:
    """Release these loans and free their robots."""
    if not ids:
        return
    conn.execute(delete(reservations).where(reservations.c.loan_id.in_(ids)))
    conn.execute(
        update(loans)
        .where(loans.c.id.in_(ids))
        .values(
            state="released",
            expires_at=None,
            reason=why,
            tell_origin=tell_origin,
            updated_at=now,
        )
    )
    add_loan_history(conn, [(i, "released", why) for i in ids], now)


def add_loan_history(
    conn: Connection, entries: list[tuple[str, str, str]], now: datetime
) -> None:
    """Add (loan id, state, detail) lines; their order is the table's own counter's."""
    if entries:
        conn.execute(
            insert(loan_history),
            [
                {"loan_id": loan_id, "state": state, "detail": detail, "at": now}
                for loan_id, state, detail in entries
            ],
        )
