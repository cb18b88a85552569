"""The statements every request runs, on SQLite's own cursor: ``SqliteRows``.

``SqlRequestStore`` speaks SQLAlchemy Core, which spends about 0.1 ms of CPU
on each statement it runs, three to four times what sqlite3 itself takes
(measured on this 2-core machine: a state change, four statements and its
transaction, 0.45 ms through Core against 0.13 ms on the cursor). Every request
runs the same few statements five or six times in its life: its row and its
history, a state change, a new request, its robots' holds. On SQLite these
run here, on the cursor of the connection SQLAlchemy has in the transaction
it opened; everything else, and every statement on PostgreSQL, stays in Core.

The rows are those Core reads and writes: times are UTC text with
microseconds (what Core's SQLite ``DATETIME`` writes, and what sorts and
compares in time order), JSON is text. The driver's errors (``sqlite3.Error``)
come out as they are; ``SqlRequestStore`` turns them into SQLAlchemy's.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from typing import Any, NamedTuple

from sqlalchemy import Connection

from robocloud.storage.records import StateChange
from robocloud.storage.rules import aware_utc
from robocloud.storage.schema import UTCDateTime, requests

# The columns of ``requests`` in the table's order, and those holding times.
REQUEST_COLUMNS = tuple(column.name for column in requests.columns)
_TIMES = frozenset(c.name for c in requests.columns if isinstance(c.type, UTCDateTime))
_ROW = f"SELECT {', '.join(REQUEST_COLUMNS)} FROM requests WHERE id = ?"
_ROW_OF = _ROW + " AND application = ?"
_HISTORY = "SELECT kind, state, detail, at FROM request_history WHERE request_id = ? ORDER BY seq"
_NEW_REQUEST = (
    f"INSERT INTO requests ({', '.join(REQUEST_COLUMNS)}) "
    f"VALUES ({', '.join('?' for _ in REQUEST_COLUMNS)})"
)
_ADD_LINE = (
    "INSERT INTO request_history (request_id, seq, kind, state, detail, at) "
    "VALUES (?, ?, ?, ?, ?, ?)"
)
_STATE = "SELECT state FROM requests WHERE id = ?"
_DROP_HOLDS = "DELETE FROM reservations WHERE request_id = ?"
_UPDATES: dict[tuple[str, ...], str] = {}  # the columns set -> an UPDATE of them
CHUNK = 500  # robots per statement: SQLite takes at most 32,766 parameters in one


class Hold(NamedTuple):
    """A row of ``reservations``, as ``SqlRequestStore`` reads it to reserve robots."""

    robot_id: str
    request_id: str | None
    loan_id: str | None
    expires_at: datetime | None


def text_time(value: datetime) -> str:
    """An aware datetime as the text SQLite keeps: UTC, with microseconds."""
    if value.tzinfo is None:
        raise ValueError("the store only takes timezone-aware datetimes")
    return value.astimezone(UTC).strftime("%Y-%m-%d %H:%M:%S.%f")


class SqliteRows:
    """The hot statements of ``SqlRequestStore`` on the open transaction's sqlite3 cursor."""

    def __init__(self, conn: Connection) -> None:
        driver = conn.connection.driver_connection
        assert isinstance(driver, sqlite3.Connection)
        self._cursor = driver.cursor()

    def request(self, request_id: str, application: str | None = None) -> dict[str, Any] | None:
        """The request's row (times as aware datetimes), or None."""
        if application is None:
            found = self._cursor.execute(_ROW, (request_id,)).fetchone()
        else:
            found = self._cursor.execute(_ROW_OF, (request_id, application)).fetchone()
        if found is None:
            return None
        row = dict(zip(REQUEST_COLUMNS, found, strict=True))
        for name in _TIMES:
            row[name] = aware_utc(row[name])
        return row

    def state(self, request_id: str) -> str | None:
        found = self._cursor.execute(_STATE, (request_id,)).fetchone()
        return None if found is None else str(found[0])

    def history(self, request_id: str) -> list[StateChange]:
        return [
            StateChange(
                state=state,
                at=aware_utc(at),  # type: ignore[arg-type]
                detail=detail,
                kind="event" if kind == "event" else "state",
            )
            for kind, state, detail, at in self._cursor.execute(_HISTORY, (request_id,))
        ]

    def new_request(self, values: Mapping[str, Any]) -> None:
        self._cursor.execute(
            _NEW_REQUEST,
            tuple(text_time(values[c]) if c in _TIMES else values[c] for c in REQUEST_COLUMNS),
        )

    def update(self, request_id: str, changed: Mapping[str, Any]) -> None:
        """Set ``changed`` (columns of ``requests``) on the request's row."""
        columns = tuple(sorted(changed))
        statement = _UPDATES.get(columns)
        if statement is None:
            unknown = set(columns) - set(REQUEST_COLUMNS)
            if unknown:
                raise ValueError(f"requests has no column {sorted(unknown)[0]!r}")
            sets = ", ".join(f"{c} = ?" for c in columns)
            statement = _UPDATES[columns] = f"UPDATE requests SET {sets} WHERE id = ?"
        values = [text_time(changed[c]) if c in _TIMES else changed[c] for c in columns]
        self._cursor.execute(statement, (*values, request_id))

    def add_line(self, request_id: str, seq: int, line: StateChange) -> None:
        self._cursor.execute(
            _ADD_LINE,
            (request_id, seq, line.kind, line.state, line.detail, text_time(line.at)),
        )

    def holds_of(self, robots: Sequence[str]) -> list[Hold]:
        """The rows of ``reservations`` that hold any of ``robots``, lapsed ones too."""
        found = []
        for start in range(0, len(robots), CHUNK):
            part = robots[start : start + CHUNK]
            marks = ", ".join("?" for _ in part)
            found += [
                Hold(robot, request, loan, aware_utc(expires))
                for robot, request, loan, expires in self._cursor.execute(
                    "SELECT robot_id, request_id, loan_id, expires_at FROM reservations "
                    f"WHERE robot_id IN ({marks})",
                    tuple(part),
                )
            ]
        return found

    def hold(
        self,
        request_id: str,
        robots: Sequence[str],
        expires_at: datetime | None,
        now: datetime,
    ) -> None:
        """New rows of ``reservations``: ``robots`` held by the request (none held now)."""
        expires = None if expires_at is None else text_time(expires_at)
        created = text_time(now)
        for start in range(0, len(robots), CHUNK):
            part = robots[start : start + CHUNK]
            marks = ", ".join("(?, ?, ?, ?)" for _ in part)
            self._cursor.execute(
                "INSERT INTO reservations (robot_id, request_id, expires_at, created_at) "
                f"VALUES {marks}",
                tuple(v for robot in part for v in (robot, request_id, expires, created)),
            )

    def drop_holds(self, request_id: str) -> None:
        self._cursor.execute(_DROP_HOLDS, (request_id,))
