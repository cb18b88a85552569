"""The tables of ``SqlRequestStore``, the same on SQLite and PostgreSQL.

::

    requests         id PK, application, label, task (JSON text), state, reason,
                     selection (JSON text), idempotency_key, created_at, updated_at
                     UNIQUE (application, idempotency_key)
    request_history  (request_id -> requests.id, seq) PK, kind, state, detail, at
    reservations     robot_id PK, request_id -> requests.id, expires_at, created_at

JSON is TEXT (``json.dumps``) so both databases store and compare it alike.
Times are UTC: ``timestamptz`` on PostgreSQL, UTC text on SQLite. The primary
key on ``reservations.robot_id`` is what keeps a robot out of two coalitions,
whichever processes share the database.
"""

from __future__ import annotations

from datetime import UTC, datetime

from sqlalchemy import (
    Column,
    DateTime,
    Dialect,
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

reservations = Table(
    "reservations",
    metadata,
    Column("robot_id", String(NAME), primary_key=True),
    Column(
        "request_id",
        String(32),
        ForeignKey("requests.id", ondelete="CASCADE"),
        nullable=False,
    ),
    Column("expires_at", UTCDateTime),
    Column("created_at", UTCDateTime, nullable=False),
    Index("ix_reservations_request", "request_id"),
)
