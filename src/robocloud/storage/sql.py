"""``SqlRequestStore``: the request store on SQLite (by default) or PostgreSQL.

SQLAlchemy Core with a sync engine; one short transaction per method,
committed before it returns. The store is composed of parts, each below it
and handed what it needs when the store is built::

    SqlRequestStore            this file: the RequestStore seam, delegating
    ├── SqlRequests            sql_requests.py: requests, history, reservations
    ├── SqlLoans               sql_loans.py: robots lent to other clouds
    ├── SqlMissions            sql_missions.py: the missions, each its latest JSON
    │   (both: sql_holds.py    who holds a robot now; lapsed holds and loans end)
    ├── create_schema          migrations.py: tables created, older stores upgraded
    └── Database               engine.py: engine, transactions, SQLite group
                               commit, retries, StoreUnavailable
    statements.py              the SQL every request runs, written once;
    sqlite_rows.py             the same statements on SQLite's own cursor

The checks and sentences are those of ``storage/rules.py``, shared with
``MemoryRequestStore``.
"""

from __future__ import annotations

import builtins
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

from robocloud.storage import rules
from robocloud.storage.engine import URL_HINT, Database, database_url
from robocloud.storage.migrations import create_schema
from robocloud.storage.records import Loan, MissionRow, RequestRecord
from robocloud.storage.sql_loans import SqlLoans
from robocloud.storage.sql_missions import SqlMissions
from robocloud.storage.sql_requests import SqlRequests
from robocloud.storage.store import Outcome

# database_url and URL_HINT are also read from here (tests/conftest.py).
__all__ = ["URL_HINT", "SqlRequestStore", "database_url"]


class SqlRequestStore:
    """A ``RequestStore`` in a SQLite file or a PostgreSQL database, created if missing.

    ``clock`` (UTC-aware datetimes) is for tests: it sets creation times and
    decides when leases lapse.
    """

    def __init__(self, url: str, *, clock: rules.Clock | None = None) -> None:
        self._db = Database(url)
        self.url = self._db.url
        self.local_reads = self._db.sqlite  # WAL: readers never wait for the writer
        self._engine = self._db.engine  # SQLAlchemy's, for event listeners in tests
        store_clock = rules.StoreClock(clock)
        self._requests = SqlRequests(self._db, store_clock)
        self._loans = SqlLoans(self._db, store_clock)
        self._missions = SqlMissions(self._db)
        try:
            self._db.run(
                partial(create_schema, sqlite=self._db.sqlite, url=self.url, rows=self._requests),
                write=True,
            )
        except BaseException:
            self.close()
            raise

    def __repr__(self) -> str:
        return f"SqlRequestStore({self.url!r})"

    def close(self) -> None:
        self._db.close()

    def together(self, calls: Sequence[Callable[[], Any]]) -> builtins.list[Outcome]:
        """Run ``calls`` in turn: on SQLite in one transaction, each in a savepoint."""
        return self._db.together(calls)

    # requests

    def create_request(
        self,
        application: str,
        task: dict[str, Any],
        label: str | None = None,
        idempotency_key: str | None = None,
    ) -> tuple[RequestRecord, bool]:
        return self._requests.create_request(application, task, label, idempotency_key)

    def by_idempotency_key(self, application: str, idempotency_key: str) -> RequestRecord | None:
        return self._requests.by_idempotency_key(application, idempotency_key)

    def get(self, request_id: str, application: str | None = None) -> RequestRecord | None:
        return self._requests.get(request_id, application)

    def list(
        self,
        application: str,
        state: str | None = None,
        limit: int = 50,
        before: str | None = None,
    ) -> tuple[builtins.list[RequestRecord], str | None]:
        return self._requests.list(application, state, limit, before)

    def transition(
        self,
        request_id: str,
        new_state: str,
        reason: str | None = None,
        detail: str | None = None,
        selection: dict[str, Any] | None = None,
    ) -> RequestRecord:
        return self._requests.transition(request_id, new_state, reason, detail, selection)

    def add_event(self, request_id: str, detail: str) -> RequestRecord:
        return self._requests.add_event(request_id, detail)

    def set_selection(self, request_id: str, selection: dict[str, Any]) -> RequestRecord:
        return self._requests.set_selection(request_id, selection)

    def active(self) -> builtins.list[RequestRecord]:
        return self._requests.active()

    # reservations

    def reserve(
        self,
        request_id: str,
        robot_ids: Sequence[str],
        lease_seconds: float | None = None,
    ) -> builtins.list[str]:
        return self._requests.reserve(request_id, robot_ids, lease_seconds)

    def confirm(self, request_id: str, robot_ids: Sequence[str]) -> builtins.list[str]:
        return self._requests.confirm(request_id, robot_ids)

    def release(self, request_id: str, robot_ids: Sequence[str] | None = None) -> None:
        self._requests.release(request_id, robot_ids)

    def replace(
        self,
        request_id: str,
        old_robot: str,
        new_robot: str,
        lease_seconds: float | None = None,
    ) -> builtins.list[str]:
        return self._requests.replace(request_id, old_robot, new_robot, lease_seconds)

    def reservations(self, request_id: str | None = None) -> dict[str, str]:
        return self._requests.reservations(request_id)

    # loans

    def lend(
        self,
        origin: str,
        request_id: str,
        robot_ids: Sequence[str],
        lease_seconds: float,
    ) -> builtins.list[str]:
        return self._loans.lend(origin, request_id, robot_ids, lease_seconds)

    def confirm_loans(
        self, origin: str, request_id: str, robot_ids: Sequence[str]
    ) -> builtins.list[str]:
        return self._loans.confirm_loans(origin, request_id, robot_ids)

    def end_loans(
        self,
        origin: str,
        request_id: str,
        robot_ids: Sequence[str] | None,
        why: str,
        *,
        tell_origin: bool = False,
    ) -> builtins.list[Loan]:
        return self._loans.end_loans(origin, request_id, robot_ids, why, tell_origin=tell_origin)

    def lapse_loans(self) -> builtins.list[Loan]:
        return self._loans.lapse_loans()

    def loan_of(self, robot_id: str) -> Loan | None:
        return self._loans.loan_of(robot_id)

    def loans(
        self, origin: str | None = None, request_id: str | None = None
    ) -> builtins.list[Loan]:
        return self._loans.loans(origin, request_id)

    def count_loans(self, origin: str) -> int:
        return self._loans.count_loans(origin)

    def untold_loans(self, origin: str) -> builtins.list[Loan]:
        return self._loans.untold_loans(origin)

    def told(self, origin: str, loan_ids: Sequence[str]) -> builtins.list[Loan]:
        return self._loans.told(origin, loan_ids)

    # missions

    def save_mission(self, row: MissionRow) -> MissionRow:
        return self._missions.save_mission(row)

    def mission(self, mission_id: str, application: str | None = None) -> MissionRow | None:
        return self._missions.mission(mission_id, application)

    def mission_by_key(self, application: str, idempotency_key: str) -> MissionRow | None:
        return self._missions.mission_by_key(application, idempotency_key)

    def missions(
        self, application: str, state: str | None, limit: int, before: str | None
    ) -> tuple[builtins.list[MissionRow], str | None]:
        return self._missions.missions(application, state, limit, before)

    def unfinished_missions(self) -> builtins.list[MissionRow]:
        return self._missions.unfinished_missions()
