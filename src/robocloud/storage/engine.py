"""``Database``: the engine and transactions of ``SqlRequestStore``, on SQLite or PostgreSQL.

Owns everything about talking to the database and nothing about what is
stored: the store URL (``database_url``), the SQLAlchemy engine and its
connection settings, one short transaction per call (``run``), the retries of
a transaction that only lost a race, and turning a database that cannot be
used into ``StoreUnavailable`` with a sentence.

SQLite runs in WAL mode with a busy timeout so several threads and processes
can share one file; a write transaction is ``BEGIN IMMEDIATE`` (one writer
at a time), and inside this process writers wait on a lock instead. Writes
that wait for each other are committed together (a group commit,
``_commit_with_others``): whoever gets the write lock runs every write
waiting at that moment, in order, in one transaction, each in a savepoint, so
each still sees the ones before it and is all or nothing. ``together`` hands
in several calls at once (the IaaS's writes, ``robocloud.iaas.store_writes``).

PostgreSQL: reads are REPEATABLE READ so a request and its history come from
one snapshot; deadlocks and serialization failures are run again.

Layer 3: imports ``robocloud.errors`` and ``storage.store`` only.
"""

from __future__ import annotations

import builtins
import random
import sqlite3
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, nullcontext, suppress
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, TypeVar

from sqlalchemy import URL, Connection, Engine, create_engine, event
from sqlalchemy.engine import make_url
from sqlalchemy.exc import (
    ArgumentError,
    DataError,
    DBAPIError,
    IntegrityError,
    ProgrammingError,
    StatementError,
)

from robocloud.errors import InvalidInput
from robocloud.storage.store import Outcome, StoreUnavailable, outcome_of

T = TypeVar("T")

URL_HINT = "use sqlite:///FILE or postgresql+psycopg://USER@HOST:PORT/DATABASE"
BUSY_TIMEOUT_S = 15.0  # how long a SQLite writer waits for another process's write
CONNECT_TIMEOUT_S = 5  # PostgreSQL
POOL_SIZE, POOL_OVERFLOW = 5, 15  # connections per store: kept, and more under load
ATTEMPTS = 20  # of a transaction that lost a race (unique violation, deadlock)
GROUP_MAX = 64  # SQLite writes committed in one transaction at most
# PostgreSQL: deadlock detected, serialization failure. Both only mean "run it again".
_TRANSIENT_SQLSTATES = frozenset({"40P01", "40001"})
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


class Database:
    """The database of one store: its engine, and each call's transaction.

    ``url`` is the store's URL without its password, for sentences;
    ``sqlite`` tells the store which of its two paths to take.
    """

    def __init__(self, url: str) -> None:
        self._url = database_url(url)
        self.url = self._url.render_as_string(hide_password=True)
        self.sqlite = self._url.get_backend_name() == "sqlite"
        # One writer at a time inside this process: SQLite serializes writers
        # anyway, and waiting on a lock is faster than its busy-retry sleeps.
        self._write_lock: threading.Lock | None = threading.Lock() if self.sqlite else None
        # SQLite writes waiting for the write lock, committed as a group, and
        # the group's connection on the thread that commits it.
        self._waiting: list[_Write] = []
        self._waiting_lock = threading.Lock()
        self._grouped = threading.local()
        # SQLite: the one connection writes use, kept while the write lock
        # passes from thread to thread (``_writer``).
        self._kept_writer: Connection | None = None
        self.engine = self._create_engine()

    def close(self) -> None:
        if self._write_lock is not None:
            with self._write_lock:
                self._drop_writer()
        self.engine.dispose()

    def unavailable(self, what: str) -> StoreUnavailable:
        """``StoreUnavailable`` with the sentence "The store at URL ``what``"."""
        return StoreUnavailable(f"The store at {self.url} {what}", self.url)

    def _create_engine(self) -> Engine:
        if not self.sqlite:
            try:
                return create_engine(
                    self._url,
                    pool_pre_ping=True,
                    pool_size=POOL_SIZE,
                    max_overflow=POOL_OVERFLOW,
                    connect_args={"connect_timeout": CONNECT_TIMEOUT_S},
                )
            except ImportError as error:
                raise self.unavailable(
                    f"needs the psycopg package (pip install 'psycopg[binary]'): {error}."
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
            # to every state change (benchmarks/results/design-notes.md,
            # synchronous-normal).
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
        with self.engine.connect() as conn:
            if write:
                conn.execution_options(**{_WRITE: True})
            elif not self.sqlite:
                conn.execution_options(isolation_level="REPEATABLE READ")
            with conn.begin():
                yield conn

    @contextmanager
    def _writer(self) -> Iterator[Connection]:
        """SQLite's write connection (the write lock held): kept from write to write.

        Checking a connection out of the pool and back in (with its reset)
        cost about a sixth of a lone state change (benchmarks/results/design-notes.md,
        kept-writer). A write that fails on the database's
        side drops the kept connection; the next write opens another.
        """
        if self._kept_writer is None:
            conn = self.engine.connect()
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

    def run(
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
                    raise  # a mistake in the store's code, not the database's state
                raise self._unavailable(error) from error

    def _unavailable(self, error: DBAPIError) -> StoreUnavailable:
        cause = str(error.orig).strip().splitlines()[0] if str(error.orig).strip() else ""
        cause = cause.removeprefix("connection failed: ").rstrip(".")
        return StoreUnavailable(f"Cannot use the store at {self.url}: {cause}.", self.url)


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
