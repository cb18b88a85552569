"""``SqlRequests``: requests, their history and their robots' reservations, in SQL.

The request half of ``SqlRequestStore``: what the store does for a request
of this cloud. Writers serialize per request: ``SELECT ... FOR UPDATE`` on the
request's row on PostgreSQL; on SQLite the write transaction already excludes
every other writer. No robot is ever reserved twice because
``reservations.robot_id`` is the primary key; when two PostgreSQL
transactions race for a robot the loser gets a unique violation, and
``reserve`` runs again (``Database.run``) and reports the robot as taken.

The statements every request runs take SQLite's own cursor (``SqliteRows``)
on SQLite and Core on PostgreSQL; both run the statements of
``robocloud.storage.statements``.
"""

from __future__ import annotations

import builtins
from collections.abc import Callable, Sequence
from typing import Any

from sqlalchemy import Connection, Row, and_, delete, or_, select, update
from sqlalchemy.exc import IntegrityError

from robocloud.domain import ACTIVE_STATES, FINAL_STATES
from robocloud.storage import rules, statements
from robocloud.storage.engine import ATTEMPTS, Database
from robocloud.storage.records import HistoryKind, RequestRecord, StateChange, new_request_id
from robocloud.storage.schema import request_history, requests, reservations
from robocloud.storage.sql_holds import live_holds
from robocloud.storage.sqlite_rows import SqliteRows


class SqlRequests:
    """The ``RequestStore`` methods of requests and reservations, on ``db``."""

    def __init__(self, db: Database, clock: rules.StoreClock) -> None:
        self._db = db
        self._clock = clock
        self._sqlite = db.sqlite

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
                conn.execute(statements.NEW_REQUEST, values)
                conn.execute(statements.ADD_LINE, [statements.line_row(request_id, 1, line)])
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
                return self._db.run(create, write=True)
            except IntegrityError:
                # Another transaction took the idempotency key (PostgreSQL;
                # SQLite writers never overlap) or, once in 2**60, the id.
                if idempotency_key is not None:
                    existing = self.by_idempotency_key(application, idempotency_key)
                    if existing is not None:
                        return existing, False
        raise self._db.unavailable("keeps refusing new requests.")

    def by_idempotency_key(self, application: str, idempotency_key: str) -> RequestRecord | None:
        return self._db.run(
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
                return (
                    None
                    if found is None
                    else statements.record(found, tuple(rows.history(request_id)))
                )
            if application is None:
                row = conn.execute(statements.ROW, {"rid": request_id}).first()
            else:
                row = conn.execute(
                    statements.ROW_OF, {"rid": request_id, "app": application}
                ).first()
            if row is None:
                return None
            history = tuple(
                statements.state_change(h)
                for h in conn.execute(statements.HISTORY, {"rid": request_id})
            )
            return statements.record(row._mapping, history)

        return self._db.run(work, write=False)

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

        return self._db.run(work, write=False)

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

            record = self.change(conn, request_id, values, "state", detail, check)
            if new_state in FINAL_STATES:
                if self._sqlite:
                    SqliteRows(conn).drop_holds(request_id)
                else:
                    conn.execute(statements.DROP_HOLDS, {"rid": request_id})
            return record

        return self._db.run(work, write=True)

    def add_event(self, request_id: str, detail: str) -> RequestRecord:
        rules.check_text(detail, "detail")

        def work(conn: Connection) -> RequestRecord:
            return self.change(conn, request_id, {}, "event", detail)

        return self._db.run(work, write=True)

    def set_selection(self, request_id: str, selection: dict[str, Any]) -> RequestRecord:
        selection_text = rules.dump_json(selection, "selection")

        def work(conn: Connection) -> RequestRecord:
            return self.change(conn, request_id, {"selection": selection_text}, None, None)

        return self._db.run(work, write=True)

    def active(self) -> builtins.list[RequestRecord]:
        def work(conn: Connection) -> builtins.list[RequestRecord]:
            rows = conn.execute(
                select(requests)
                .where(requests.c.state.in_(sorted(ACTIVE_STATES)))
                .order_by(requests.c.created_at, requests.c.id)
            ).all()
            return self._records(conn, rows)

        return self._db.run(work, write=False)

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

        return self._db.run(work, write=True, retry_integrity=True)

    def confirm(self, request_id: str, robot_ids: Sequence[str]) -> builtins.list[str]:
        return self.reserve(request_id, robot_ids)

    def release(self, request_id: str, robot_ids: Sequence[str] | None = None) -> None:
        robots = None if robot_ids is None else rules.check_robots(robot_ids)

        def work(conn: Connection) -> None:
            statement = delete(reservations).where(reservations.c.request_id == request_id)
            if robots is not None:
                statement = statement.where(reservations.c.robot_id.in_(robots))
            conn.execute(statement)

        self._db.run(work, write=True)

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

        return self._db.run(work, write=True, retry_integrity=True)

    def reservations(self, request_id: str | None = None) -> dict[str, str]:
        def work(conn: Connection) -> dict[str, str]:
            now = self._clock()
            query = (
                select(reservations.c.robot_id, reservations.c.request_id, reservations.c.loan_id)
                .where(statements.unexpired(reservations.c.expires_at, now))
                .order_by(reservations.c.robot_id)
            )
            if request_id is not None:
                query = query.where(reservations.c.request_id == request_id)
            return {row.robot_id: row.request_id or row.loan_id for row in conn.execute(query)}

        return self._db.run(work, write=False)

    # rows

    def change(
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
            found = conn.execute(statements.ROW_FOR_UPDATE, {"rid": request_id}).first()
            row = None if found is None else dict(found._mapping)
        if row is None:
            raise rules.no_such_request(request_id)
        if check is not None:
            check(row["state"])
        history = (
            sqlite.history(request_id)
            if sqlite is not None
            else [
                statements.state_change(h)
                for h in conn.execute(statements.HISTORY, {"rid": request_id})
            ]
        )
        now = self._clock()
        changed = {**values, "updated_at": now}
        if sqlite is not None:
            sqlite.update(request_id, changed)
        else:
            conn.execute(
                statements.update_of(frozenset(changed)),
                statements.update_params(request_id, changed),
            )
        if line is not None:
            state = str(changed.get("state", row["state"]))
            history.append(StateChange(state=state, at=now, detail=detail, kind=line))
            if sqlite is not None:
                sqlite.add_line(request_id, len(history), history[-1])
            else:
                conn.execute(
                    statements.ADD_LINE,
                    [statements.line_row(request_id, len(history), history[-1])],
                )
        return statements.record({**row, **changed}, tuple(history))

    def _lock(self, conn: Connection, request_id: str) -> str:
        """Lock the request's row until the transaction ends and return its state.

        FOR UPDATE is a no-op on SQLite, whose write transaction already
        excludes every other writer.
        """
        if self._sqlite:
            state = SqliteRows(conn).state(request_id)
        else:
            state = conn.execute(
                statements.STATE_FOR_UPDATE, {"rid": request_id}
            ).scalar_one_or_none()
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
        held = {row.robot_id: row for row in live_holds(conn, robots, now, sqlite=self._sqlite)}
        taken = [r for r in robots if r in held and held[r].request_id != request_id]
        if taken:
            return taken
        new = sorted(r for r in robots if r not in held)  # one order: no deadlocks
        if new and self._sqlite:
            SqliteRows(conn).hold(request_id, new, expires_at, now)
        elif new:
            conn.execute(
                statements.hold(len(new)),
                {
                    "rid": request_id,
                    "expires": expires_at,
                    "created": now,
                    **statements.robot_params(new),
                },
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
                history[line.request_id].append(statements.state_change(line))
        return [statements.record(row._mapping, tuple(history[row.id])) for row in rows]
