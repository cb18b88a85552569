"""One store suite over three backends: memory, a SQLite file, PostgreSQL.

PostgreSQL tests run in a database made for this session
(``robocloud_test_<hex>``, dropped at the end) on the server tests/conftest.py
finds or starts (``postgres_url``). Without one they fail, never skip: CI must
run them.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from sqlalchemy import Engine, create_engine, inspect
from storage_testing import Backend, FakeClock

from robocloud.storage import RequestStore
from robocloud.storage.schema import metadata


@pytest.fixture(scope="session")
def postgres_cleaner(postgres_url: str) -> Iterator[Engine]:
    engine = create_engine(postgres_url)
    yield engine
    engine.dispose()


def _empty(engine: Engine) -> None:
    """Each test starts with no rows; the tables stay, as a restarted IaaS finds them."""
    with engine.begin() as conn:
        found = inspect(conn)
        if found.has_table("requests"):
            for table in reversed(metadata.sorted_tables):
                if found.has_table(table.name):  # a table newer than the database's
                    conn.execute(table.delete())


def _backend(name: str, request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Backend]:
    if name == "memory":
        backend = Backend(name, None)
    elif name == "sqlite":
        backend = Backend(name, f"sqlite:///{tmp_path / 'store.db'}")
    else:
        url = request.getfixturevalue("postgres_url")
        _empty(request.getfixturevalue("postgres_cleaner"))
        backend = Backend(name, url)
    yield backend
    backend.close()


@pytest.fixture(params=["memory", "sqlite", "postgresql"])
def backend(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Backend]:
    yield from _backend(request.param, request, tmp_path)


@pytest.fixture(params=["sqlite", "postgresql"])
def sql_backend(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Backend]:
    yield from _backend(request.param, request, tmp_path)


@pytest.fixture
def store(backend: Backend) -> RequestStore:
    return backend.open()


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock()
