"""``SqlRequestStore``: the request store on SQLite (by default) or PostgreSQL.

SQLAlchemy Core with a sync engine; one short transaction per method, committed
before it returns. Writers serialize per request: ``SELECT ... FOR UPDATE`` on
the request's row on PostgreSQL, ``BEGIN IMMEDIATE`` (one writer at a time) on
SQLite, which runs in WAL mode with a busy timeout so several threads and
processes can share one file. Reads on PostgreSQL are REPEATABLE READ so a
request and its history come from one snapshot.

On SQLite, writes that wait for each other are committed together (a group
commit, ``_commit_with_others``): whoever gets the write lock runs every write
waiting at that moment, in order, in one transaction, each in a savepoint, so
each still sees the ones before it and is all or nothing. ``together`` hands
in several calls at once (the IaaS's writes, ``robocloud.iaas.store_writes``).

No robot is ever reserved twice because ``reservations.robot_id`` is the
primary key; when two PostgreSQL transactions race for a robot the loser gets a
unique violation, and ``reserve`` (or ``lend``) runs again and reports the
robot as taken. Loans hold their robots in the same table, so a robot lent to
another cloud is never reserved by a request of this one, nor the reverse.
"""

from __future__ import annotations

import builtins
import logging
import random
import sqlite3
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager, nullcontext, suppress
from dataclasses import dataclass
from datetime import datetime
from functools import partial
from pathlib import Path
from typing import Any, TypeVar

from sqlalchemy import (
    URL,
    Connection,
    Engine,
    Row,
    and_,
    bindparam,
    create_engine,
    delete,
    event,
    insert,
    inspect,
    or_,
    select,
    text,
    update,
)
from sqlalchemy.engine import make_url
from sqlalchemy.exc import (
    ArgumentError,
    DataError,
    DBAPIError,
    IntegrityError,
    ProgrammingError,
    StatementError,
)

from robocloud.domain import ACTIVE_STATES, FINAL_STATES
from robocloud.errors import InvalidInput
from robocloud.storage import rules
from robocloud.storage.records import (
    HistoryKind,
    Loan,
    RequestRecord,
    StateChange,
    new_loan_id,
    new_request_id,
)
from robocloud.storage.schema import (
    loan_history,
    loans,
    metadata,
    request_history,
    requests,
    reservations,
)
from robocloud.storage.sqlite_rows import SqliteRows
from robocloud.storage.store import Outcome, StoreUnavailable, outcome_of

# The statements of a request's writes, built once: building and keying a Core
# statement cost more than running it (measured: 5.3 ms per transition with
# six statements built per call; see SqlRequestStore._change).
_ROW_FOR_UPDATE = select(requests).where(requests.c.id == bindparam("rid")).with_for_update()
_ROW = select(requests).where(requests.c.id == bindparam("rid"))
_HISTORY = (
    select(request_history)
    .where(request_history.c.request_id == bindparam("rid"))
    .order_by(request_history.c.seq)
)
_ROW_OF = _ROW.where(requests.c.application == bindparam("app"))
_STATE_FOR_UPDATE = (
    select(requests.c.state).where(requests.c.id == bindparam("rid")).with_for_update()
)
_HOLDS_OF = select(
    reservations.c.robot_id,
    reservations.c.request_id,
    reservations.c.loan_id,
    reservations.c.expires_at,
).where(reservations.c.robot_id.in_(bindparam("robots", expanding=True)))
_ADD_LINE = insert(request_history)
_NEW_REQUEST = insert(requests)
_DROP_HOLDS = delete(reservations).where(reservations.c.request_id == bindparam("rid"))
_UPDATES: dict[frozenset[str], Any] = {}  # the columns set -> an UPDATE of them


def _update_of(columns: frozenset[str]) -> Any:
    statement = _UPDATES.get(columns)
    if statement is None:
        statement = _UPDATES[columns] = (
            update(requests)
            .where(requests.c.id == bindparam("rid"))
            .values({c: bindparam(f"new_{c}") for c in sorted(columns)})
        )
    return statement

T = TypeVar("T")
_ACTIVE_LOANS = ("leased", "firm")  # as a list, not != released: the state index serves it
log = logging.getLogger(__name__)

URL_HINT = "use sqlite:///FILE or postgresql+psycopg://USER@HOST:PORT/DATABASE"
BUSY_TIMEOUT_S = 15.0  # how long a SQLite writer waits for another process's write
CONNECT_TIMEOUT_S = 5  # PostgreSQL
POOL_SIZE, POOL_OVERFLOW = 5, 15  # connections per store: kept, and more under load
ATTEMPTS = 20  # of a transaction that lost a race (unique violation, deadlock)
GROUP_MAX = 64  # SQLite writes committed in one transaction at most
# PostgreSQL: deadlock detected, serialization failure. Both only mean "run it again".
_TRANSIENT_SQLSTATES = frozenset({"40P01", "40001"})
_SCHEMA_LOCK = 0x726F626F  # pg_advisory_xact_lock key while creating the tables
_WRITE = "robocloud_write"  # execution option: this SQLite transaction will write


def database_url(url: str) -> URL:
    """The SQLAlchemy URL of a store URL, or ``InvalidInput`` with a sentence.

    ``postgresql://`` and ``postgres://`` mean ``postgresql+psycopg://``.
    """

    def refuse(why: str = "") -> InvalidInput:
        return InvalidInput(
            f"store URL {url!r} is not a supported database URL{why}; {URL_HINT}.", "store_url"
        )

    try:
        parsed = make_url(url)
    except (ArgumentError, ValueError, TypeError) as error:
        raise refuse() from error
    backend, _, driver = parsed.drivername.partition("+")
    if backend in {"postgresql", "postgres"} and driver in {"", "psycopg"}:
        return parsed.set(drivername="postgresql+psycopg")
    if backend == "sqlite" and driver in {"", "pysqlite"}:
        if parsed.database in {None, "", ":memory:"} or (parsed.database or "").startswith("file:"):
            raise refuse(" (an in-memory SQLite database; use memory:// for a store in memory)")
        return parsed.set(drivername="sqlite+pysqlite")
    raise refuse()


class SqlRequestStore:
    """A ``RequestStore`` in a SQLite file or a PostgreSQL database, created if missing.

    ``clock`` (UTC-aware datetimes) is for tests: it sets creation times and
    decides when leases lapse.
    """

    def __init__(self, url: str, *, clock: rules.Clock | None = None) -> None:
        self._url = database_url(url)
        self.url = self._url.render_as_string(hide_password=True)
        self._clock = rules.StoreClock(clock)
        self._sqlite = self._url.get_backend_name() == "sqlite"
        self.local_reads = self._sqlite  # WAL: readers never wait for the writer
        # One writer at a time inside this process: SQLite serializes writers
        # anyway, and waiting on a lock is faster than its busy-retry sleeps.
        self._write_lock: threading.Lock | None = threading.Lock() if self._sqlite else None
        # SQLite writes waiting for the write lock, committed as a group, and
        # the group's connection on the thread that commits it.
        self._waiting: list[_Write] = []
        self._waiting_lock = threading.Lock()
        self._grouped = threading.local()
        # SQLite: the one connection writes use, kept while the write lock
        # passes from thread to thread (``_writer``).
        self._kept_writer: Connection | None = None
        self._engine = self._create_engine()
        try:
            self._run(self._create_schema, write=True)
        except BaseException:
            self.close()
            raise

    def __repr__(self) -> str:
        return f"SqlRequestStore({self.url!r})"

    # requests

    def create_request(
        self,
        application: str,
        task: dict[str, Any],
        label: str | None = None,
        idempotency_key: str | None = None,
    ) -> tuple[RequestRecord, bool]:
        rules.check_name(application, "application", "application")
        rules.check_optional_name(idempotency_key, "idempotency_key", "idempotency_key")
        rules.check_text(label, "label")
        task_text = rules.dump_json(task, "task")

        def create(conn: Connection) -> tuple[RequestRecord, bool]:
            if idempotency_key is not None:
                existing = self._by_key(conn, application, idempotency_key)
                if existing is not None:
                    return existing, False
            request_id = new_request_id()
            now = self._clock()
            values = {
                "id": request_id,
                "application": application,
                "label": label,
                "task": task_text,
                "state": "received",
                "reason": None,
                "selection": None,
                "created_at": now,
                "updated_at": now,
                "idempotency_key": idempotency_key,
            }
            line = StateChange(state="received", at=now)
            if self._sqlite:
                rows = SqliteRows(conn)
                rows.new_request(values)
                rows.add_line(request_id, 1, line)
            else:
                conn.execute(_NEW_REQUEST, values)
                conn.execute(_ADD_LINE, [_line_row(request_id, 1, line)])
            record = RequestRecord(
                id=request_id,
                application=application,
                label=label,
                task=rules.load_json(task_text),
                state="received",
                reason=None,
                created_at=now,
                updated_at=now,
                selection=None,
                idempotency_key=idempotency_key,
                history=(line,),
            )
            return record, True

        for _ in range(ATTEMPTS):
            try:
                return self._run(create, write=True)
            except IntegrityError:
                # Another transaction took the idempotency key (PostgreSQL;
                # SQLite writers never overlap) or, once in 2**60, the id.
                if idempotency_key is not None:
                    existing = self.by_idempotency_key(application, idempotency_key)
                    if existing is not None:
                        return existing, False
        raise StoreUnavailable(f"The store at {self.url} keeps refusing new requests.", self.url)

    def by_idempotency_key(self, application: str, idempotency_key: str) -> RequestRecord | None:
        return self._run(
            lambda conn: self._by_key(conn, application, idempotency_key), write=False
        )

    def _by_key(
        self, conn: Connection, application: str, idempotency_key: str
    ) -> RequestRecord | None:
        row = conn.execute(
            select(requests).where(
                requests.c.application == application,
                requests.c.idempotency_key == idempotency_key,
            )
        ).first()
        return None if row is None else self._records(conn, [row])[0]

    def get(self, request_id: str, application: str | None = None) -> RequestRecord | None:
        def work(conn: Connection) -> RequestRecord | None:
            if self._sqlite:
                rows = SqliteRows(conn)
                found = rows.request(request_id, application)
                return None if found is None else _record(found, tuple(rows.history(request_id)))
            if application is None:
                row = conn.execute(_ROW, {"rid": request_id}).first()
            else:
                row = conn.execute(_ROW_OF, {"rid": request_id, "app": application}).first()
            if row is None:
                return None
            history = tuple(_state_change(h) for h in conn.execute(_HISTORY, {"rid": request_id}))
            return _record(row._mapping, history)

        return self._run(work, write=False)

    def list(
        self,
        application: str,
        state: str | None = None,
        limit: int = 50,
        before: str | None = None,
    ) -> tuple[builtins.list[RequestRecord], str | None]:
        if state is not None:
            rules.check_state(state)
        rules.check_limit(limit)

        def work(conn: Connection) -> tuple[builtins.list[RequestRecord], str | None]:
            query = select(requests).where(requests.c.application == application)
            if state is not None:
                query = query.where(requests.c.state == state)
            if before is not None:
                edge = conn.execute(
                    select(requests.c.created_at).where(
                        requests.c.id == before, requests.c.application == application
                    )
                ).scalar_one_or_none()
                if edge is None:
                    raise rules.bad_cursor(before)
                query = query.where(
                    or_(
                        requests.c.created_at < edge,
                        and_(requests.c.created_at == edge, requests.c.id < before),
                    )
                )
            query = query.order_by(requests.c.created_at.desc(), requests.c.id.desc())
            rows = conn.execute(query.limit(limit + 1)).all()
            page = self._records(conn, rows[:limit])
            return page, (page[-1].id if len(rows) > limit else None)

        return self._run(work, write=False)

    def transition(
        self,
        request_id: str,
        new_state: str,
        reason: str | None = None,
        detail: str | None = None,
        selection: dict[str, Any] | None = None,
    ) -> RequestRecord:
        selection_text = rules.check_transition(new_state, reason, detail, selection)

        values: dict[str, Any] = {"state": new_state}
        if reason is not None:
            values["reason"] = reason
        if selection_text is not None:
            values["selection"] = selection_text

        def work(conn: Connection) -> RequestRecord:
            def check(current: str) -> None:
                rules.check_move(request_id, current, new_state)

            record = self._change(conn, request_id, values, "state", detail, check)
            if new_state in FINAL_STATES:
                if self._sqlite:
                    SqliteRows(conn).drop_holds(request_id)
                else:
                    conn.execute(_DROP_HOLDS, {"rid": request_id})
            return record

        return self._run(work, write=True)

    def add_event(self, request_id: str, detail: str) -> RequestRecord:
        rules.check_text(detail, "detail")

        def work(conn: Connection) -> RequestRecord:
            return self._change(conn, request_id, {}, "event", detail)

        return self._run(work, write=True)

    def set_selection(self, request_id: str, selection: dict[str, Any]) -> RequestRecord:
        selection_text = rules.dump_json(selection, "selection")

        def work(conn: Connection) -> RequestRecord:
            return self._change(conn, request_id, {"selection": selection_text}, None, None)

        return self._run(work, write=True)

    def active(self) -> builtins.list[RequestRecord]:
        def work(conn: Connection) -> builtins.list[RequestRecord]:
            rows = conn.execute(
                select(requests)
                .where(requests.c.state.in_(sorted(ACTIVE_STATES)))
                .order_by(requests.c.created_at, requests.c.id)
            ).all()
            return self._records(conn, rows)

        return self._run(work, write=False)

    # reservations

    def reserve(
        self,
        request_id: str,
        robot_ids: Sequence[str],
        lease_seconds: float | None = None,
    ) -> builtins.list[str]:
        robots = rules.check_robots(robot_ids)
        rules.lease_end(self._clock(), lease_seconds)  # check it before any work

        def work(conn: Connection) -> builtins.list[str]:
            self._lock_holder(conn, request_id)
            return self._hold(conn, request_id, robots, lease_seconds)

        return self._run(work, write=True, retry_integrity=True)

    def confirm(self, request_id: str, robot_ids: Sequence[str]) -> builtins.list[str]:
        return self.reserve(request_id, robot_ids)

    def release(self, request_id: str, robot_ids: Sequence[str] | None = None) -> None:
        robots = None if robot_ids is None else rules.check_robots(robot_ids)

        def work(conn: Connection) -> None:
            statement = delete(reservations).where(reservations.c.request_id == request_id)
            if robots is not None:
                statement = statement.where(reservations.c.robot_id.in_(robots))
            conn.execute(statement)

        self._run(work, write=True)

    def replace(
        self,
        request_id: str,
        old_robot: str,
        new_robot: str,
        lease_seconds: float | None = None,
    ) -> builtins.list[str]:
        rules.check_name(old_robot, "a robot id", "old_robot")
        robots = rules.check_robots([new_robot])
        rules.lease_end(self._clock(), lease_seconds)

        def work(conn: Connection) -> builtins.list[str]:
            self._lock_holder(conn, request_id)
            taken = self._hold(conn, request_id, robots, lease_seconds)
            if not taken and old_robot != new_robot:
                conn.execute(
                    delete(reservations).where(
                        reservations.c.request_id == request_id,
                        reservations.c.robot_id == old_robot,
                    )
                )
            return taken

        return self._run(work, write=True, retry_integrity=True)

    def reservations(self, request_id: str | None = None) -> dict[str, str]:
        def work(conn: Connection) -> dict[str, str]:
            now = self._clock()
            query = (
                select(reservations.c.robot_id, reservations.c.request_id, reservations.c.loan_id)
                .where(_unexpired(reservations.c.expires_at, now))
                .order_by(reservations.c.robot_id)
            )
            if request_id is not None:
                query = query.where(reservations.c.request_id == request_id)
            return {row.robot_id: row.request_id or row.loan_id for row in conn.execute(query)}

        return self._run(work, write=False)

    # loans

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
            held = {row.robot_id: row for row in self._live_holds(conn, robots, now)}
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
                self._loan_history(
                    conn, [(ids[r], "leased", f"lent to {origin}") for r in new], now
                )
                holds = [
                    {"robot_id": r, "loan_id": ids[r], "expires_at": expires_at, "created_at": now}
                    for r in new
                ]
                # The robots' race is decided here (the primary key): one multi-row
                # INSERT for several, as _hold does; one robot needs no more.
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

        return self._run(work, write=True, retry_integrity=True)

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

        return self._run(work, write=True)

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
                    loans.c.state.in_(_ACTIVE_LOANS),
                )
                .order_by(loans.c.id)
                .with_for_update()
            )
            if robots is not None:
                query = query.where(loans.c.robot_id.in_(robots))
            ids = [row.id for row in conn.execute(query)]
            self._end_loans(conn, ids, now, why, tell_origin)
            return self._loans_by_id(conn, ids, history=False)

        return self._run(work, write=True)

    def lapse_loans(self) -> builtins.list[Loan]:
        def work(conn: Connection) -> builtins.list[Loan]:
            now = self._clock()
            lapsed = conn.execute(
                select(reservations.c.robot_id, reservations.c.loan_id).where(
                    reservations.c.loan_id.is_not(None), reservations.c.expires_at < now
                )
            ).all()
            ids = self._drop(conn, lapsed, now)
            return self._loans_by_id(conn, ids, history=False)

        return self._run(work, write=True)

    def loan_of(self, robot_id: str) -> Loan | None:
        def work(conn: Connection) -> Loan | None:
            loan_id = conn.execute(
                select(reservations.c.loan_id).where(
                    reservations.c.robot_id == robot_id,
                    reservations.c.loan_id.is_not(None),
                    _unexpired(reservations.c.expires_at, self._clock()),
                )
            ).scalar_one_or_none()
            if loan_id is None:
                return None
            return self._loans_by_id(conn, [loan_id], history=True)[0]

        return self._run(work, write=False)

    def loans(
        self, origin: str | None = None, request_id: str | None = None
    ) -> builtins.list[Loan]:
        def work(conn: Connection) -> builtins.list[Loan]:
            query = select(loans).where(
                loans.c.state.in_(_ACTIVE_LOANS), _unexpired(loans.c.expires_at, self._clock())
            )
            if origin is not None:
                query = query.where(loans.c.origin == origin)
            if request_id is not None:
                query = query.where(loans.c.request_id == request_id)
            rows = conn.execute(
                query.order_by(loans.c.created_at, loans.c.robot_id, loans.c.id)
            ).all()
            return [_loan(row) for row in rows]

        return self._run(work, write=False)

    def untold_loans(self, origin: str) -> builtins.list[Loan]:
        def work(conn: Connection) -> builtins.list[Loan]:
            rows = conn.execute(
                select(loans)
                .where(loans.c.origin == origin, loans.c.tell_origin.is_(True))
                .order_by(loans.c.updated_at, loans.c.id)
            ).all()
            return [_loan(row) for row in rows]

        return self._run(work, write=False)

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
                self._loan_history(
                    conn,
                    [(i, "released", f"{origin} was told that the loan ended") for i in marked],
                    now,
                )
            return self._loans_by_id(conn, marked, history=False)

        return self._run(work, write=True)

    def close(self) -> None:
        if self._write_lock is not None:
            with self._write_lock:
                self._drop_writer()
        self._engine.dispose()

    # transactions

    def _create_engine(self) -> Engine:
        if not self._sqlite:
            try:
                return create_engine(
                    self._url,
                    pool_pre_ping=True,
                    pool_size=POOL_SIZE,
                    max_overflow=POOL_OVERFLOW,
                    connect_args={"connect_timeout": CONNECT_TIMEOUT_S},
                )
            except ImportError as error:
                raise StoreUnavailable(
                    f"The store at {self.url} needs the psycopg package "
                    f"(pip install 'psycopg[binary]'): {error}.",
                    self.url,
                ) from error
        folder = Path(self._url.database or "").parent
        if not folder.is_dir():
            raise StoreUnavailable(
                f"Cannot open the store at {self.url}: the folder {folder} does not exist.",
                self.url,
            )
        engine = create_engine(
            self._url,
            pool_size=POOL_SIZE,
            max_overflow=POOL_OVERFLOW,
            connect_args={"timeout": BUSY_TIMEOUT_S, "check_same_thread": False},
        )

        @event.listens_for(engine, "connect")
        def _on_connect(dbapi_connection: Any, _record: Any) -> None:
            # The driver must not open transactions itself; _on_begin does.
            dbapi_connection.isolation_level = None
            cursor = dbapi_connection.cursor()
            cursor.execute(f"PRAGMA busy_timeout = {int(BUSY_TIMEOUT_S * 1000)}")
            cursor.execute("PRAGMA journal_mode = WAL")
            # In WAL mode NORMAL still survives a crash of the process (kill -9):
            # a commit is in the WAL before it returns; only a power loss or an
            # OS crash may take back the last commits. FULL would add an fsync
            # (about 3 ms here) to every state change.
            cursor.execute("PRAGMA synchronous = NORMAL")
            cursor.execute("PRAGMA foreign_keys = ON")
            cursor.close()

        @event.listens_for(engine, "begin")
        def _on_begin(connection: Connection) -> None:
            # IMMEDIATE takes the write lock up front: a deferred transaction
            # that reads and then writes can fail at once in WAL mode
            # instead of waiting its turn.
            writes = connection.get_execution_options().get(_WRITE, False)
            connection.exec_driver_sql("BEGIN IMMEDIATE" if writes else "BEGIN")

        return engine

    @contextmanager
    def _transaction(self, *, write: bool, locked: bool = False) -> Iterator[Connection]:
        """One transaction; a SQLite write takes the write lock unless ``locked`` (held)."""
        if write and self._write_lock is not None:
            lock = nullcontext() if locked else self._write_lock
            with lock, self._writer() as conn, conn.begin():
                yield conn
            return
        with self._engine.connect() as conn:
            if write:
                conn.execution_options(**{_WRITE: True})
            elif not self._sqlite:
                conn.execution_options(isolation_level="REPEATABLE READ")
            with conn.begin():
                yield conn

    @contextmanager
    def _writer(self) -> Iterator[Connection]:
        """SQLite's write connection (the write lock held): kept from write to write.

        Checking a connection out of the pool and back in (with its reset)
        cost about a sixth of a lone state change (measured: 0.38 to 0.41 ms of
        CPU per write with it, 0.32 to 0.37 ms without). A write that fails on the database's
        side drops the kept connection; the next write opens another.
        """
        if self._kept_writer is None:
            conn = self._engine.connect()
            conn.execution_options(**{_WRITE: True})
            self._kept_writer = conn
        try:
            yield self._kept_writer
        except DBAPIError:
            self._drop_writer()
            raise

    def _drop_writer(self) -> None:
        kept, self._kept_writer = self._kept_writer, None
        if kept is not None:
            with suppress(Exception):  # a broken connection may not close cleanly
                kept.close()

    def _run(
        self,
        work: Callable[[Connection], T],
        *,
        write: bool,
        retry_integrity: bool = False,
    ) -> T:
        """``work`` in one transaction, run again when it only lost a race."""
        grouped: Connection | None = getattr(self._grouped, "conn", None)
        if grouped is not None:
            # A call of a group, on the thread that commits it: in its transaction.
            try:
                return work(grouped)
            except sqlite3.Error as error:  # a statement of SqliteRows
                raise _as_sqlalchemy(error) from error
        if write and self._write_lock is not None:
            value: T = self._commit_with_others([_Write(work, retry_integrity)])[0].get()
            return value
        return self._run_alone(work, write=write, retry_integrity=retry_integrity)

    def together(self, calls: Sequence[Callable[[], Any]]) -> builtins.list[Outcome]:
        """Run ``calls`` in turn: on SQLite in one transaction, each in a savepoint."""
        if self._write_lock is None:
            return [outcome_of(call) for call in calls]  # PostgreSQL: writers run side by side
        writes = [_Write(partial(_without_connection, call), False) for call in calls]
        return self._commit_with_others(writes)

    def _commit_with_others(self, mine: builtins.list[_Write]) -> builtins.list[Outcome]:
        """SQLite writes, committed with every write waiting when the write lock is free.

        SQLite has one writer at a time, and each transaction costs its BEGIN,
        COMMIT and a connection on top of its statements. Under load the
        writes line up here; whoever gets the lock runs every waiting write
        (its own among them, or done already) in one transaction, in the
        order they came, each in a savepoint (``_commit_group``).
        """
        assert self._write_lock is not None
        with self._waiting_lock:
            self._waiting.extend(mine)
        with self._write_lock:
            while not all(write.done for write in mine):
                with self._waiting_lock:
                    group = self._waiting[:GROUP_MAX]
                    del self._waiting[:GROUP_MAX]
                try:
                    self._commit_group(group)
                finally:
                    for write in group:  # only when interrupted: no write waits forever
                        if not write.done:
                            write.outcome = Outcome(
                                error=StoreUnavailable(
                                    f"A write to the store at {self.url} was interrupted.",
                                    self.url,
                                )
                            )
        return [write.outcome for write in mine if write.outcome is not None]

    def _commit_group(self, group: builtins.list[_Write]) -> None:
        """Run and commit ``group`` (the write lock held); every write gets its outcome.

        Each write runs in a savepoint: one that fails is rolled back alone,
        and the others are committed. A write whose own statement the database
        refused (a ``DBAPIError`` or ``sqlite3.Error``: it may have lost a
        race) runs again alone after the group, with the retries of
        ``_run_alone``. When the group's transaction itself cannot be begun or
        committed (the file is locked by another process past the busy
        timeout, the disk is full), nothing of it was stored and every write
        gets that error at once: run again one by one, each would wait out the
        same busy timeout.
        """
        if len(group) == 1:
            group[0].outcome = outcome_of(partial(self._alone, group[0]))
            return
        outcomes: builtins.list[Outcome | None] = []
        try:
            with self._transaction(write=True, locked=True) as conn:
                cursor = conn.connection.driver_connection.cursor()  # type: ignore[union-attr]
                for write in group:
                    cursor.execute("SAVEPOINT one_write")
                    outcome = self._in_group(conn, write.work)
                    if outcome.error is not None:
                        cursor.execute("ROLLBACK TO one_write")
                    cursor.execute("RELEASE one_write")
                    refused = isinstance(outcome.error, DBAPIError | sqlite3.Error)
                    outcomes.append(None if refused else outcome)
        except Exception as error:
            failed = Outcome(error=self._as_unavailable(error))
            for write in group:
                write.outcome = failed
            return
        for write, found in zip(group, outcomes, strict=True):
            write.outcome = outcome_of(partial(self._alone, write)) if found is None else found

    def _as_unavailable(self, error: Exception) -> Exception:
        """The error a write gets when its group could not be stored."""
        if isinstance(error, sqlite3.Error):
            error = _as_sqlalchemy(error)
        if isinstance(error, DBAPIError):
            return self._unavailable(error)
        return error

    def _alone(self, write: _Write) -> Any:
        """``write`` in a transaction of its own (the write lock held)."""
        return self._run_alone(
            partial(self._grouped_work, write.work),
            write=True,
            retry_integrity=write.retry_integrity,
            locked=True,
        )

    def _grouped_work(self, work: Callable[[Connection], T], conn: Connection) -> T:
        value: T = self._in_group(conn, work).get()
        return value

    def _in_group(self, conn: Connection, work: Callable[[Connection], Any]) -> Outcome:
        """``work`` on ``conn``, where the store's own calls also use ``conn``."""
        self._grouped.conn = conn
        try:
            return outcome_of(lambda: work(conn))
        finally:
            self._grouped.conn = None

    def _run_alone(
        self,
        work: Callable[[Connection], T],
        *,
        write: bool,
        retry_integrity: bool = False,
        locked: bool = False,
    ) -> T:
        """``work`` in a transaction of its own, run again when it only lost a race."""
        attempt = 0
        while True:
            attempt += 1
            try:
                with self._transaction(write=write, locked=locked) as conn:
                    try:
                        return work(conn)
                    except sqlite3.Error as error:  # a statement of SqliteRows
                        raise _as_sqlalchemy(error) from error
            except IntegrityError:
                if retry_integrity and attempt < ATTEMPTS:
                    continue
                raise
            except DBAPIError as error:
                sqlstate = getattr(error.orig, "sqlstate", None)
                if sqlstate in _TRANSIENT_SQLSTATES and attempt < ATTEMPTS:
                    time.sleep(random.uniform(0, 0.002 * attempt))
                    continue
                if isinstance(error, ProgrammingError | DataError) and not (
                    error.connection_invalidated
                ):
                    raise  # a mistake in this module, not the database's state
                raise self._unavailable(error) from error

    def _unavailable(self, error: DBAPIError) -> StoreUnavailable:
        cause = str(error.orig).strip().splitlines()[0] if str(error.orig).strip() else ""
        cause = cause.removeprefix("connection failed: ").rstrip(".")
        return StoreUnavailable(f"Cannot use the store at {self.url}: {cause}.", self.url)

    def _create_schema(self, conn: Connection) -> None:
        if not self._sqlite:
            # Two processes opening a new database must not both create the tables.
            conn.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": _SCHEMA_LOCK})
        found = inspect(conn)
        if found.has_table("reservations") and "loan_id" not in {
            column["name"] for column in found.get_columns("reservations")
        }:
            self._migrate_to_loans(conn)
        metadata.create_all(conn)

    def _migrate_to_loans(self, conn: Connection) -> None:
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
            self._change(
                conn,
                shadow,
                {"state": "canceled"},
                "state",
                "shadow requests gave way to loans",
            )
        rows = [
            {
                **row,
                "expires_at": rules.aware_utc(row["expires_at"]),
                "created_at": rules.aware_utc(row["created_at"]),
            }
            for row in kept
            if row["request_id"] not in set(shadows)
        ]
        if rows:
            conn.execute(insert(reservations).values(rows))
        log.warning(
            "store %s: moved to loans (%d reservations kept, %d shadow requests ended)",
            self.url,
            len(rows),
            len(shadows),
        )

    # loans' rows

    def _live_holds(
        self, conn: Connection, robots: builtins.list[str], now: datetime
    ) -> builtins.list[Any]:
        """The holds on ``robots`` that have not lapsed; lapsed ones are deleted (free).

        A lapsed lease is free, whoever held it; a lapsed loan ends.
        """
        rows: Sequence[Any] = (
            SqliteRows(conn).holds_of(robots)
            if self._sqlite
            else conn.execute(_HOLDS_OF, {"robots": robots}).all()
        )
        lapsed = [row for row in rows if rules.is_expired(row.expires_at, now)]
        if lapsed:
            self._drop(conn, lapsed, now)
        return [row for row in rows if not rules.is_expired(row.expires_at, now)]

    def _drop(self, conn: Connection, lapsed: Sequence[Any], now: datetime) -> builtins.list[str]:
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
        self._end_loans(conn, ended, now, "the lease lapsed", False)
        return ended

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
                loans.c.state.in_(_ACTIVE_LOANS),
                _unexpired(loans.c.expires_at, now),
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
        self._loan_history(conn, [(i, "firm", why) for i in ids], now)

    def _end_loans(
        self,
        conn: Connection,
        ids: builtins.list[str],
        now: datetime,
        why: str,
        tell_origin: bool,
    ) -> None:
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
        self._loan_history(conn, [(i, "released", why) for i in ids], now)

    def _loan_history(
        self, conn: Connection, entries: builtins.list[tuple[str, str, str]], now: datetime
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

    # rows

    def _lock(self, conn: Connection, request_id: str) -> str:
        """Lock the request's row until the transaction ends and return its state.

        FOR UPDATE is a no-op on SQLite, whose write transaction already
        excludes every other writer.
        """
        if self._sqlite:
            state = SqliteRows(conn).state(request_id)
        else:
            state = conn.execute(_STATE_FOR_UPDATE, {"rid": request_id}).scalar_one_or_none()
        if state is None:
            raise rules.no_such_request(request_id)
        return str(state)

    def _lock_holder(self, conn: Connection, request_id: str) -> None:
        rules.check_can_hold_robots(request_id, self._lock(conn, request_id))

    def _hold(
        self,
        conn: Connection,
        request_id: str,
        robots: builtins.list[str],
        lease_seconds: float | None,
    ) -> builtins.list[str]:
        """Reserve ``robots`` for the (locked) request, or return those another holds."""
        now = self._clock()
        expires_at = rules.lease_end(now, lease_seconds)
        held = {row.robot_id: row for row in self._live_holds(conn, robots, now)}
        taken = [r for r in robots if r in held and held[r].request_id != request_id]
        if taken:
            return taken
        new = sorted(r for r in robots if r not in held)  # one order: no deadlocks
        if new and self._sqlite:
            SqliteRows(conn).hold(request_id, new, expires_at, now)
        elif new:
            # One multi-row INSERT (not executemany, which psycopg pipelines
            # and then logs the unique violation of a lost race as an error).
            conn.execute(
                insert(reservations).values(
                    [
                        {
                            "robot_id": r,
                            "request_id": request_id,
                            "expires_at": expires_at,
                            "created_at": now,
                        }
                        for r in new
                    ]
                )
            )
        leased = [r for r in robots if r in held and held[r].expires_at is not None]
        if leased:
            extend = update(reservations).where(reservations.c.robot_id.in_(leased))
            if expires_at is None:
                conn.execute(extend.values(expires_at=None))
            else:
                conn.execute(
                    extend.where(reservations.c.expires_at < expires_at).values(
                        expires_at=expires_at
                    )
                )
        return []

    def _change(
        self,
        conn: Connection,
        request_id: str,
        values: dict[str, Any],
        line: HistoryKind | None,
        detail: str | None,
        check: Callable[[str], None] | None = None,
    ) -> RequestRecord:
        """Lock the request's row, set ``values``, add a history line of ``line``'s kind.

        Four statements: the row (locked) and its history are read, the row
        updated and the line added; the record returned is built from them,
        not read back. The row lock makes the line's number safe.
        """
        sqlite = SqliteRows(conn) if self._sqlite else None
        if sqlite is not None:
            row = sqlite.request(request_id)
        else:
            found = conn.execute(_ROW_FOR_UPDATE, {"rid": request_id}).first()
            row = None if found is None else dict(found._mapping)
        if row is None:
            raise rules.no_such_request(request_id)
        if check is not None:
            check(row["state"])
        history = (
            sqlite.history(request_id)
            if sqlite is not None
            else [_state_change(h) for h in conn.execute(_HISTORY, {"rid": request_id})]
        )
        now = self._clock()
        changed = {**values, "updated_at": now}
        if sqlite is not None:
            sqlite.update(request_id, changed)
        else:
            conn.execute(
                _update_of(frozenset(changed)),
                {"rid": request_id, **{f"new_{c}": v for c, v in changed.items()}},
            )
        if line is not None:
            state = str(changed.get("state", row["state"]))
            history.append(StateChange(state=state, at=now, detail=detail, kind=line))
            if sqlite is not None:
                sqlite.add_line(request_id, len(history), history[-1])
            else:
                conn.execute(_ADD_LINE, [_line_row(request_id, len(history), history[-1])])
        return _record({**row, **changed}, tuple(history))

    def _load(self, conn: Connection, request_id: str) -> RequestRecord:
        row = conn.execute(_ROW, {"rid": request_id}).one()
        return self._records(conn, [row])[0]

    def _records(self, conn: Connection, rows: Sequence[Row[Any]]) -> builtins.list[RequestRecord]:
        history: dict[str, builtins.list[StateChange]] = {row.id: [] for row in rows}
        ids = builtins.list(history)
        for start in range(0, len(ids), 500):
            lines = conn.execute(
                select(request_history)
                .where(request_history.c.request_id.in_(ids[start : start + 500]))
                .order_by(request_history.c.request_id, request_history.c.seq)
            )
            for line in lines:
                history[line.request_id].append(_state_change(line))
        return [_record(row._mapping, tuple(history[row.id])) for row in rows]


@dataclass(eq=False)
class _Write:
    """A SQLite write waiting for its group commit, then its outcome."""

    work: Callable[[Connection], Any]
    retry_integrity: bool
    outcome: Outcome | None = None

    @property
    def done(self) -> bool:
        return self.outcome is not None


def _as_sqlalchemy(error: sqlite3.Error) -> StatementError:
    """A driver error of ``SqliteRows`` as SQLAlchemy raises it, for the retry and
    "unavailable" rules (``IntegrityError`` for a constraint, ``OperationalError``...)."""
    return DBAPIError.instance(None, None, error, sqlite3.Error)


def _without_connection(call: Callable[[], T], _conn: Connection) -> T:
    """A call of ``together`` as the work of a write: the store's calls find the connection."""
    return call()


def _state_change(line: Row[Any]) -> StateChange:
    return StateChange(
        state=line.state,
        at=line.at,
        detail=line.detail,
        kind="event" if line.kind == "event" else "state",
    )


def _line_row(request_id: str, seq: int, line: StateChange) -> dict[str, Any]:
    return {
        "request_id": request_id,
        "seq": seq,
        "kind": line.kind,
        "state": line.state,
        "detail": line.detail,
        "at": line.at,
    }


def _record(row: Mapping[Any, Any], history: tuple[StateChange, ...]) -> RequestRecord:
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


def _unexpired(column: Any, now: datetime) -> Any:
    """A hold or loan that has not lapsed at ``now`` (None: it never lapses)."""
    return or_(column.is_(None), column >= now)


def _loan(row: Row[Any], history: tuple[StateChange, ...] = ()) -> Loan:
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
