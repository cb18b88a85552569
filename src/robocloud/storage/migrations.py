"""Creating the store's tables (``schema``) and bringing an older store up to date.

``create_schema`` runs once when a ``SqlRequestStore`` opens, in one write
transaction: it upgrades a store made by an older robocloud, then creates
whatever table or index is missing. On PostgreSQL an advisory lock keeps two
processes opening a new database from both creating the tables.

Upgrades, oldest first:
- ``to_loans``: another cloud's hold on a robot was a "shadow" request; it
  is a loan now.
- missions: a store made before them gains the ``missions`` table (and its
  indexes) from ``create_all``; nothing else changes.
"""

from __future__ import annotations

import logging

from sqlalchemy import Connection, insert, inspect, select, text

from robocloud.domain import ACTIVE_STATES
from robocloud.storage import rules
from robocloud.storage.schema import metadata, requests, reservations
from robocloud.storage.sql_requests import SqlRequests

_SCHEMA_LOCK = 0x726F626F  # pg_advisory_xact_lock key while creating the tables
log = logging.getLogger(__name__)


def create_schema(conn: Connection, *, sqlite: bool, url: str, rows: SqlRequests) -> None:
    """Upgrade an older store and create what is missing (``url`` names it in the log)."""
    if not sqlite:
        # Two processes opening a new database must not both create the tables.
        conn.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": _SCHEMA_LOCK})
    found = inspect(conn)
    if found.has_table("reservations") and "loan_id" not in {
        column["name"] for column in found.get_columns("reservations")
    }:
        to_loans(conn, url, rows)
    metadata.create_all(conn)


def to_loans(conn: Connection, url: str, rows: SqlRequests) -> None:
    """Bring a store made before loans up to date, in the schema transaction.

    Such a store kept another cloud's hold on a robot as a "shadow" request
    (application ``cloud:<origin>``). The reservations table is made anew
    (a holder is now a request or a loan) with the requests' holds; the
    active shadows end, so their robots are free: the origins' requests
    lose them as robots whose loans ended (nothing tells those origins,
    which ran the old protocol).
    """
    kept = [
        dict(row._mapping)
        for row in conn.execute(
            text("SELECT robot_id, request_id, expires_at, created_at FROM reservations")
        )
    ]
    conn.execute(text("DROP TABLE reservations"))
    metadata.create_all(conn)
    shadows = (
        conn.execute(
            select(requests.c.id).where(
                requests.c.application.like("cloud:%"),
                requests.c.state.in_(sorted(ACTIVE_STATES)),
            )
        )
        .scalars()
        .all()
    )
    for shadow in shadows:
        rows.change(
            conn,
            shadow,
            {"state": "canceled"},
            "state",
            "shadow requests gave way to loans",
        )
    holds = [
        {
            **row,
            "expires_at": rules.aware_utc(row["expires_at"]),
            "created_at": rules.aware_utc(row["created_at"]),
        }
        for row in kept
        if row["request_id"] not in set(shadows)
    ]
    if holds:
        conn.execute(insert(reservations).values(holds))
    log.warning(
        "store %s: moved to loans (%d reservations kept, %d shadow requests ended)",
        url,
        len(holds),
        len(shadows),
    )

