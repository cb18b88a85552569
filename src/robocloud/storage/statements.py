"""The statements a request runs, each written once, and the rows they read and write.

Both paths of ``SqlRequestStore`` run these: SQLAlchemy Core executes them on
PostgreSQL, and ``SqliteRows`` runs the same statements, compiled once to
SQLite's text, on the driver's own cursor. Parameters are named (``:rid``),
so both paths pass the same names.

Also here: turning the rows these statements read into ``RequestRecord``
and ``StateChange``, on either path.

Layer 3, below every other SQL module: imports ``schema``, ``records`` and
``rules`` only.
"""

from __future__ import annotations

from collections.abc import Mapping
from datetime import datetime
from functools import cache, lru_cache
from typing import Any

from sqlalchemy import Delete, Insert, Select, Update, bindparam, delete, insert, or_, select
from sqlalchemy import update as update_statement

from robocloud.storage import rules
from robocloud.storage.records import RequestRecord, StateChange
from robocloud.storage.schema import request_history, requests, reservations

# Built once: building and keying a Core statement cost more than running it
# (benchmarks/results/design-notes.md, statements-once; ``SqlRequests.change``).
ROW_FOR_UPDATE: Select[Any] = (
    select(requests).where(requests.c.id == bindparam("rid")).with_for_update()
)
ROW: Select[Any] = select(requests).where(requests.c.id == bindparam("rid"))
ROW_OF: Select[Any] = ROW.where(requests.c.application == bindparam("app"))
STATE_FOR_UPDATE: Select[Any] = (
    select(requests.c.state).where(requests.c.id == bindparam("rid")).with_for_update()
)
HISTORY: Select[Any] = (
    select(
        request_history.c.kind,
        request_history.c.state,
        request_history.c.detail,
        request_history.c.at,
    )
    .where(request_history.c.request_id == bindparam("rid"))
    .order_by(request_history.c.seq)
)
NEW_REQUEST: Insert = insert(requests)  # the parameters: every column of ``requests``
ADD_LINE: Insert = insert(request_history)  # the parameters: ``line_row``
DROP_HOLDS: Delete = delete(reservations).where(reservations.c.request_id == bindparam("rid"))

REQUEST_COLUMNS = tuple(column.name for column in requests.columns)


@cache  # one per set of columns a store's code sets: a handful
def update_of(columns: frozenset[str]) -> Update:
    """An UPDATE of the request ``:rid`` setting ``columns``, each from ``:new_<column>``."""
    return (
        update_statement(requests)
        .where(requests.c.id == bindparam("rid"))
        .values({c: bindparam(f"new_{c}") for c in sorted(columns)})
    )


def update_params(request_id: str, changed: Mapping[str, Any]) -> dict[str, Any]:
    """The parameters of ``update_of(frozenset(changed))``."""
    return {"rid": request_id, **{f"new_{c}": v for c, v in changed.items()}}


def _holds_of(robots: Any) -> Select[Any]:
    return select(
        reservations.c.robot_id,
        reservations.c.request_id,
        reservations.c.loan_id,
        reservations.c.expires_at,
    ).where(reservations.c.robot_id.in_(robots))


# The holds on ``:robots`` (a list), lapsed ones too.
HOLDS_OF: Select[Any] = _holds_of(bindparam("robots", expanding=True))


@lru_cache(maxsize=64)
def holds_of(count: int) -> Select[Any]:
    """``HOLDS_OF`` for exactly ``count`` robots, ``:robot_0`` ...: for drivers' own text."""
    return _holds_of([bindparam(f"robot_{i}") for i in range(count)])


@lru_cache(maxsize=64)
def hold(count: int) -> Insert:
    """``count`` robots (``:robot_0`` ...) held by the request ``:rid`` until ``:expires``.

    One multi-row INSERT (not executemany, which psycopg pipelines and then
    logs the unique violation of a lost race as an error); ``:created`` is now.
    """
    return insert(reservations).values(
        [
            {
                "robot_id": bindparam(f"robot_{i}"),
                "request_id": bindparam("rid"),
                "expires_at": bindparam("expires", type_=reservations.c.expires_at.type),
                "created_at": bindparam("created", type_=reservations.c.created_at.type),
            }
            for i in range(count)
        ]
    )


def robot_params(robots: list[str] | tuple[str, ...]) -> dict[str, str]:
    """The ``:robot_<i>`` parameters of ``holds_of`` and ``hold``."""
    return {f"robot_{i}": robot for i, robot in enumerate(robots)}


def unexpired(column: Any, now: datetime) -> Any:
    """A hold or loan that has not lapsed at ``now`` (None: it never lapses)."""
    return or_(column.is_(None), column >= now)


def line_row(request_id: str, seq: int, line: StateChange) -> dict[str, Any]:
    """The parameters of ``ADD_LINE``."""
    return {
        "request_id": request_id,
        "seq": seq,
        "kind": line.kind,
        "state": line.state,
        "detail": line.detail,
        "at": line.at,
    }


def state_change(line: Any) -> StateChange:
    """A line of ``request_history`` (kind, state, detail, at)."""
    return StateChange(
        state=line.state,
        at=line.at,
        detail=line.detail,
        kind="event" if line.kind == "event" else "state",
    )


def record(row: Mapping[Any, Any], history: tuple[StateChange, ...]) -> RequestRecord:
    """A row of ``requests`` (times as aware datetimes) and its history."""
    selection = row["selection"]
    return RequestRecord(
        id=row["id"],
        application=row["application"],
        label=row["label"],
        task=rules.load_json(row["task"]),
        state=row["state"],
        reason=row["reason"],
        created_at=row["created_at"],
        updated_at=row["updated_at"],
        selection=None if selection is None else rules.load_json(selection),
        idempotency_key=row["idempotency_key"],
        history=history,
    )

