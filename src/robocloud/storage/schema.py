"""The tables of ``SqlRequestStore``, the same on SQLite and PostgreSQL.

::

    requests         id PK, application, label, task (JSON text), state, reason,
                     selection (JSON text), idempotency_key, created_at, updated_at
                     UNIQUE (application, idempotency_key)
    request_history  (request_id -> requests.id, seq) PK, kind, state, detail, at
    reservations     robot_id PK, request_id -> requests.id | loan_id -> loans.id,
                     expires_at, created_at
    loans            id PK, robot_id, origin, request_id (the origin's), state,
                     expires_at, reason, tell_origin, created_at, updated_at
    loan_history     id PK (a counter), loan_id -> loans.id, state, detail, at
    missions         id PK, application, idempotency_key, state, created_at (unix
                     seconds), document (JSON text: the mission as the API shows it)
                     UNIQUE (application, idempotency_key)

JSON is TEXT (``json.dumps``) so both databases store and compare it alike.
Times are UTC: ``timestamptz`` on PostgreSQL, UTC text on SQLite. The primary
key on ``reservations.robot_id`` is what keeps a robot out of two coalitions,
whichever processes share the database: a reservation row is held either by a
request of this cloud or by a loan to another cloud's request (exactly one of
``request_id`` and ``loan_id``), so local requests and loans share the one
guarantee. ``loans`` keeps every loan, ended ones too, as their history.
"""

from __future__ import annotations

from datetime import UTC, datetime

from sqlalchemy import (
    Boolean,
    CheckConstraint,
    Column,
    DateTime,
    Dialect,
    Float,
    ForeignKey,
    Index,
    Integer,
    MetaData,
    PrimaryKeyConstraint,
    String,
    Table,
    Text,
    TypeDecorator,
    UniqueConstraint,
)

from robocloud.storage.rules import MAX_NAME as NAME


class UTCDateTime(TypeDecorator[datetime]):
    """Aware UTC datetimes in, aware UTC datetimes out, on either database."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            raise ValueError("the store only takes timezone-aware datetimes")
        value = value.astimezone(UTC)
        # SQLite keeps text; naive UTC text sorts and compares in time order.
        return value.replace(tzinfo=None) if dialect.name == "sqlite" else value

    def process_result_value(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


metadata = MetaData()

requests = Table(
    "requests",
    metadata,
    Column("id", String(32), primary_key=True),
    Column("application", String(NAME), nullable=False),
    Column("label", Text),
    Column("task", Text, nullable=False),
    Column("state", String(16), nullable=False),
    Column("reason", Text),
    Column("selection", Text),
    Column("idempotency_key", String(NAME)),
    Column("created_at", UTCDateTime, nullable=False),
    Column("updated_at", UTCDateTime, nullable=False),
    UniqueConstraint("application", "idempotency_key", name="uq_requests_idempotency"),
    Index("ix_requests_application_created", "application", "created_at", "id"),
    Index("ix_requests_state_created", "state", "created_at"),
)

request_history = Table(
    "request_history",
    metadata,
    Column(
        "request_id",
        String(32),
        ForeignKey("requests.id", ondelete="CASCADE"),
        nullable=False,
    ),
    Column("seq", Integer, nullable=False),
    Column("kind", String(8), nullable=False),
    Column("state", String(16), nullable=False),
    Column("detail", Text),
    Column("at", UTCDateTime, nullable=False),
    PrimaryKeyConstraint("request_id", "seq", name="pk_request_history"),
)

loans = Table(
    "loans",
    metadata,
    Column("id", String(32), primary_key=True),
    Column("robot_id", String(NAME), nullable=False),
    Column("origin", String(NAME), nullable=False),
    Column("request_id", String(NAME), nullable=False),
    Column("state", String(16), nullable=False),
    Column("expires_at", UTCDateTime),
    Column("reason", Text),
    Column("tell_origin", Boolean, nullable=False, default=False),
    Column("created_at", UTCDateTime, nullable=False),
    Column("updated_at", UTCDateTime, nullable=False),
    Index("ix_loans_origin_request", "origin", "request_id"),
    Index("ix_loans_robot", "robot_id"),
    Index("ix_loans_origin_tell", "origin", "tell_origin"),
    # The live loans among all the ended ones the table keeps.
    Index("ix_loans_state", "state"),
)

loan_history = Table(
    "loan_history",
    metadata,
    # A counter, not (loan, seq): a line is added without reading the last one.
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("loan_id", String(32), ForeignKey("loans.id", ondelete="CASCADE"), nullable=False),
    Column("state", String(16), nullable=False),
    Column("detail", Text),
    Column("at", UTCDateTime, nullable=False),
    Index("ix_loan_history_loan", "loan_id", "id"),
)

# Missions (robocloud.iaas.missions): a table a store made before them gains
# when it opens (``metadata.create_all`` creates what is missing).
missions = Table(
    "missions",
    metadata,
    Column("id", String(32), primary_key=True),
    Column("application", String(NAME), nullable=False),
    Column("idempotency_key", String(NAME)),
    Column("state", String(16), nullable=False),
    Column("created_at", Float, nullable=False),
    Column("document", Text, nullable=False),
    UniqueConstraint("application", "idempotency_key", name="uq_missions_idempotency"),
    Index("ix_missions_application_created", "application", "created_at", "id"),
    Index("ix_missions_state", "state"),
)

reservations = Table(
    "reservations",
    metadata,
    Column("robot_id", String(NAME), primary_key=True),
    Column("request_id", String(32), ForeignKey("requests.id", ondelete="CASCADE")),
    Column("loan_id", String(32), ForeignKey("loans.id", ondelete="CASCADE")),
    Column("expires_at", UTCDateTime),
    Column("created_at", UTCDateTime, nullable=False),
    CheckConstraint("(request_id IS NULL) <> (loan_id IS NULL)", name="ck_reservations_one_holder"),
    Index("ix_reservations_request", "request_id"),
    Index("ix_reservations_loan", "loan_id"),
)
