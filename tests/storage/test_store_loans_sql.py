"""Loans in the SQL store: they survive a restart, and a store made before loans is moved on."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

from sqlalchemy import (
    Column,
    ForeignKey,
    Index,
    MetaData,
    String,
    Table,
    create_engine,
    insert,
    inspect,
)
from storage_testing import Backend, new_in

from robocloud.storage.schema import UTCDateTime, metadata, request_history, requests


def test_loans_survive_close_and_reopen(sql_backend: Backend) -> None:
    store = sql_backend.open()
    store.lend("cloud-a", "req-a1", ["b-1", "b-2"], 600)
    store.confirm_loans("cloud-a", "req-a1", ["b-1"])
    store.end_loans("cloud-a", "req-a1", ["b-2"], "cloud-a was away", tell_origin=True)
    before = (store.loans(), store.loan_of("b-1"), store.untold_loans("cloud-a"))
    store.close()
    reopened = sql_backend.open()
    assert (
        reopened.loans(),
        reopened.loan_of("b-1"),
        reopened.untold_loans("cloud-a"),
    ) == before
    assert reopened.reserve(new_in(reopened, "selecting"), ["b-1"]) == ["b-1"]


def old_schema() -> MetaData:
    """The tables as robocloud made them before loans: the same requests and history
    (constraints and indexes included), and reservations held by requests only."""
    old = MetaData()
    requests.to_metadata(old)
    request_history.to_metadata(old)
    Table(
        "reservations",
        old,
        Column("robot_id", String(255), primary_key=True),
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
    return old


def test_a_store_made_before_loans_is_moved_on(sql_backend: Backend) -> None:
    assert sql_backend.url is not None
    engine = create_engine(sql_backend.url)
    now = datetime.now(UTC).replace(microsecond=0)
    with engine.begin() as conn:
        metadata.drop_all(conn)
        old = old_schema()
        old.create_all(conn)
        rows = [
            ("req-local00001", "wildfire", "dispatched"),
            ("req-shadow0001", "cloud:cloud-a", "dispatched"),
            ("req-shadow0002", "cloud:cloud-a", "completed"),
        ]
        for request_id, application, state in rows:
            conn.execute(
                insert(old.tables["requests"]).values(
                    id=request_id,
                    application=application,
                    task="{}",
                    state=state,
                    created_at=now,
                    updated_at=now,
                )
            )
            conn.execute(
                insert(old.tables["request_history"]).values(
                    request_id=request_id, seq=1, kind="state", state="received", at=now
                )
            )
        conn.execute(
            insert(old.tables["reservations"]).values(
                [
                    {"robot_id": "b-1", "request_id": "req-local00001", "created_at": now},
                    {
                        "robot_id": "b-2",
                        "request_id": "req-local00001",
                        "expires_at": now + timedelta(hours=1),
                        "created_at": now,
                    },
                    {"robot_id": "b-3", "request_id": "req-shadow0001", "created_at": now},
                ]
            )
        )
    engine.dispose()

    store = sql_backend.open()
    assert store.reservations() == {"b-1": "req-local00001", "b-2": "req-local00001"}
    shadow = store.get("req-shadow0001")
    assert shadow is not None and shadow.state == "canceled"
    assert shadow.history[-1].detail == "shadow requests gave way to loans"
    assert store.lend("cloud-a", "req-a1", ["b-3"], 30) == []
    assert store.lend("cloud-a", "req-a1", ["b-1"], 30) == ["b-1"]
    assert [r.id for r in store.active()] == ["req-local00001"]
    engine = create_engine(sql_backend.url)
    columns = {c["name"] for c in inspect(engine).get_columns("reservations")}
    engine.dispose()
    assert {"loan_id", "request_id"} <= columns
    # The tables are today's again, constraints included (the next tests use them).
    engine = create_engine(sql_backend.url)
    found = inspect(engine)
    assert {u["name"] for u in found.get_unique_constraints("requests")} == {
        "uq_requests_idempotency"
    }
    assert {c["name"] for c in found.get_check_constraints("reservations")} == {
        "ck_reservations_one_holder"
    }
    engine.dispose()
    # Opening it again finds nothing to move.
    again = sql_backend.open()
    assert again.reservations() == store.reservations()
    assert again.get("req-local00001") == store.get("req-local00001")
