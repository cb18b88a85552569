"""The statements every request runs, on SQLite's own cursor: ``SqliteRows``.

``SqlRequestStore`` speaks SQLAlchemy Core, which spends several times the
CPU that sqlite3 itself takes on each statement it runs
(benchmarks/results/design-notes.md, sqlite-cursor). Every request
runs the same few statements five or six times in its life: its row and its
history, a state change, a new request, its robots' holds. On SQLite these
run here, on the cursor of the connection SQLAlchemy has in the transaction
it opened; everything else, and every statement on PostgreSQL, stays in Core.

The statements are those of ``robocloud.storage.statements``, compiled once
to SQLite's text: the SQL is written there only. The rows are those Core reads
and writes: times are UTC text with microseconds (what Core's SQLite
``DATETIME`` writes, and what sorts and compares in time order), JSON is text.
The driver's errors (``sqlite3.Error``) come out as they are; the store's
engine (``robocloud.storage.engine``) turns them into SQLAlchemy's.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from typing import Any, NamedTuple

from sqlalchemy import Connection
from sqlalchemy.dialects import sqlite
from sqlalchemy.sql import ClauseElement

from robocloud.storage import statements
from robocloud.storage.records import StateChange
from robocloud.storage.rules import aware_utc
from robocloud.storage.schema import UTCDateTime, requests
from robocloud.storage.statements import REQUEST_COLUMNS

_DIALECT = sqlite.dialect(paramstyle="named")  # :name, as sqlite3 takes with a dict


def sqlite_text(statement: ClauseElement) -> str:
    """``statement`` as SQLite's text, with named parameters."""
    return str(statement.compile(dialect=_DIALECT))


_TIMES = frozenset(c.name for c in requests.columns if isinstance(c.type, UTCDateTime))
_ROW = sqlite_text(statements.ROW)
_ROW_OF = sqlite_text(statements.ROW_OF)
_STATE = sqlite_text(statements.STATE_FOR_UPDATE)  # FOR UPDATE: nothing on SQLite
_HISTORY = sqlite_text(statements.HISTORY)
_NEW_REQUEST = sqlite_text(statements.NEW_REQUEST)
_ADD_LINE = sqlite_text(statements.ADD_LINE)
_DROP_HOLDS = sqlite_text(statements.DROP_HOLDS)
_UPDATES: dict[frozenset[str], str] = {}  # the columns set -> an UPDATE of them
_HOLDS_OF: dict[int, str] = {}  # robots in one statement -> its text
_HOLD: dict[int, str] = {}
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


def _text_times(values: Mapping[str, Any]) -> dict[str, Any]:
    return {c: text_time(v) if c in _TIMES and v is not None else v for c, v in values.items()}


class SqliteRows:
    """The hot statements of ``SqlRequestStore`` on the open transaction's sqlite3 cursor."""

    def __init__(self, conn: Connection) -> None:
        driver = conn.connection.driver_connection
        assert isinstance(driver, sqlite3.Connection)
        self._cursor = driver.cursor()

    def request(self, request_id: str, application: str | None = None) -> dict[str, Any] | None:
        """The request's row (times as aware datetimes), or None."""
        if application is None:
            found = self._cursor.execute(_ROW, {"rid": request_id}).fetchone()
        else:
            found = self._cursor.execute(
                _ROW_OF, {"rid": request_id, "app": application}
            ).fetchone()
        if found is None:
            return None
        row = dict(zip(REQUEST_COLUMNS, found, strict=True))
        for name in _TIMES:
            row[name] = aware_utc(row[name])
        return row

    def state(self, request_id: str) -> str | None:
        found = self._cursor.execute(_STATE, {"rid": request_id}).fetchone()
        return None if found is None else str(found[0])

    def history(self, request_id: str) -> list[StateChange]:
        return [
            StateChange(
                state=state,
                at=aware_utc(at),  # type: ignore[arg-type]
                detail=detail,
                kind="event" if kind == "event" else "state",
            )
            for kind, state, detail, at in self._cursor.execute(_HISTORY, {"rid": request_id})
        ]

    def new_request(self, values: Mapping[str, Any]) -> None:
        """A new row of ``requests``: ``values`` has every column."""
        self._cursor.execute(_NEW_REQUEST, _text_times(values))

    def update(self, request_id: str, changed: Mapping[str, Any]) -> None:
        """Set ``changed`` (columns of ``requests``) on the request's row."""
        columns = frozenset(changed)
        statement = _UPDATES.get(columns)
        if statement is None:
            unknown = columns - set(REQUEST_COLUMNS)
            if unknown:
                raise ValueError(f"requests has no column {sorted(unknown)[0]!r}")
            statement = _UPDATES[columns] = sqlite_text(statements.update_of(columns))
        self._cursor.execute(
            statement, statements.update_params(request_id, _text_times(changed))
        )

    def add_line(self, request_id: str, seq: int, line: StateChange) -> None:
        row = statements.line_row(request_id, seq, line)
        self._cursor.execute(_ADD_LINE, {**row, "at": text_time(line.at)})

    def holds_of(self, robots: Sequence[str]) -> list[Hold]:
        """The rows of ``reservations`` that hold any of ``robots``, lapsed ones too."""
        found = []
        for start in range(0, len(robots), CHUNK):
            part = tuple(robots[start : start + CHUNK])
            statement = _HOLDS_OF.get(len(part))
            if statement is None:
                statement = _HOLDS_OF[len(part)] = sqlite_text(statements.holds_of(len(part)))
            found += [
                Hold(robot, request, loan, aware_utc(expires))
                for robot, request, loan, expires in self._cursor.execute(
                    statement, statements.robot_params(part)
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
            part = tuple(robots[start : start + CHUNK])
            statement = _HOLD.get(len(part))
            if statement is None:
                statement = _HOLD[len(part)] = sqlite_text(statements.hold(len(part)))
            self._cursor.execute(
                statement,
                {
                    "rid": request_id,
                    "expires": expires,
                    "created": created,
                    **statements.robot_params(part),
                },
            )

    def drop_holds(self, request_id: str) -> None:
        self._cursor.execute(_DROP_HOLDS, {"rid": request_id})
