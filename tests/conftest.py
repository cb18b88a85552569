"""What every test folder shares: the markers by folder, a PostgreSQL database for the session.

Markers are given here, by where a test is and what it uses, so a test file
needs none of its own (``make check`` leaves out the last three):

- ``system``: everything under ``tests/system/``: real IaaS and simulator processes;
- ``browser``: every ``test_*browser*.py``: Debian's chromium driven by Playwright;
- ``postgres``: a test that uses the PostgreSQL server (a ``postgres_*`` fixture,
  or the ``postgresql`` case of a parametrized backend);
- ``slow``: system and browser tests, besides any a test file marks itself.

PostgreSQL tests run in a database made for this session
(``robocloud_test_<hex>``, dropped at the end) on the server of
``ROBOCLOUD_TEST_POSTGRES_URL``, else the one on 127.0.0.1:5432, else one the
run starts itself; the VDA 5050 tests share an MQTT broker found or started
the same way (``session_servers.py`` says how). With no server to be had they
fail, never skip: CI must run them.

Order: the slowest files run first (``SLOWEST_FIRST``, then the other slow
ones), so that ``make test``'s workers (``--dist loadfile``: a file stays on
one worker) end together instead of one of them starting a long file last.
"""

from __future__ import annotations

import secrets
from collections.abc import Iterator
from pathlib import Path

import pytest
from sqlalchemy import Engine, create_engine, text
from sqlalchemy.exc import DBAPIError

from robocloud.storage.sql import database_url
from session_servers import ServerUnavailable, close_run, mqtt_broker, open_run, postgres_admin_url

TESTS = Path(__file__).parent
SYSTEM_FOLDER = "system"
POSTGRES_FIXTURES = frozenset({"postgres_admin", "postgres_url", "postgres_cleaner"})
# The longest files of `make test`, longest first (README, "Tests", has the
# measured seconds); a file not named here but marked slow comes after them.
SLOWEST_FIRST = (
    "wildfire/test_wildfire_browser.py",
    "system/test_federation.py",
    "system/test_vda5050.py",
    "wildfire/test_wildfire_faults.py",
    "system/test_missions.py",
    "system/test_one_cloud.py",
    "system/test_robot_truth.py",
    "wildfire/test_wildfire_bandwidth.py",
    "wildfire/test_wildfire_mission_page.py",
    "system/test_api_fuzz.py",
    "system/test_robots_are_told.py",
    "system/test_secure_federation.py",
    "system/test_store_outage.py",
    "wildfire/test_wildfire_mission_system.py",
    "system/test_nxt.py",
    "federation/test_loans_over_zenoh.py",
    "cli/test_startup.py",
    "selection/test_exact.py",
    "system/test_demo.py",
    "gateways/test_vda5050_gateway.py",
    "storage/test_store_loans.py",
    "system/test_ros2_robot_check.py",
    "system/test_ros2.py",
    "conformance/test_robot_check.py",
    "system/test_http_connections.py",
    "gateways/test_nxt_robot_check.py",
    "iaas/test_lifecycle.py",
)


def markers_of(item: pytest.Item) -> set[str]:
    """The markers a test gets from its place and its fixtures."""
    path = item.path.relative_to(TESTS) if item.path.is_relative_to(TESTS) else item.path
    names: set[str] = set()
    if path.parts[0] == SYSTEM_FOLDER:
        names |= {"system", "slow"}
    if path.name.startswith("test_") and "browser" in path.name:
        names |= {"browser", "slow"}
    fixtures = set(getattr(item, "fixturenames", ()))
    callspec = getattr(item, "callspec", None)
    params = callspec.params.values() if callspec is not None else ()
    if fixtures & POSTGRES_FIXTURES or "postgresql" in params:
        names.add("postgres")
    return names


def pytest_configure(config: pytest.Config) -> None:
    # Before xdist starts its workers, so that they share the servers the run starts.
    open_run()


def pytest_unconfigure(config: pytest.Config) -> None:
    close_run()


def run_order(item: pytest.Item) -> tuple[int, int]:
    """Where an item's file comes in the run: the slowest first (a stable sort keeps the rest)."""
    path = item.path.relative_to(TESTS).as_posix() if item.path.is_relative_to(TESTS) else ""
    if path in SLOWEST_FIRST:
        return 0, SLOWEST_FIRST.index(path)
    return (1 if item.get_closest_marker("slow") else 2), 0


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        for name in sorted(markers_of(item)):
            item.add_marker(name)
    items.sort(key=run_order)


@pytest.fixture(scope="session")
def postgres_admin() -> Iterator[Engine]:
    try:
        admin_url = postgres_admin_url()
    except ServerUnavailable as error:
        pytest.fail(str(error), pytrace=False)
    engine = create_engine(
        database_url(admin_url),
        isolation_level="AUTOCOMMIT",
        connect_args={"connect_timeout": 5},
    )
    try:
        with engine.connect() as conn:
            conn.execute(text("SELECT 1"))
    except DBAPIError as error:
        engine.dispose()
        cause = str(error.orig).strip().splitlines()[0]
        pytest.fail(
            f"PostgreSQL is not usable at {admin_url} ({cause}): the storage tests must run "
            "against it; fix that server, or point ROBOCLOUD_TEST_POSTGRES_URL at another.",
            pytrace=False,
        )
    yield engine
    engine.dispose()


@pytest.fixture(scope="session")
def postgres_url(postgres_admin: Engine) -> Iterator[str]:
    """A fresh database for this test session, dropped at its end."""
    name = f"robocloud_test_{secrets.token_hex(6)}"
    with postgres_admin.connect() as conn:
        conn.execute(text(f'CREATE DATABASE "{name}"'))
    try:
        yield postgres_admin.url.set(database=name).render_as_string(hide_password=False)
    finally:
        with postgres_admin.connect() as conn:
            conn.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))


@pytest.fixture(scope="session")
def mosquitto() -> tuple[str, int]:
    """The MQTT broker the VDA 5050 tests share (Mosquitto, or amqtt), each on topics of its own."""
    try:
        return mqtt_broker()
    except ServerUnavailable as error:
        pytest.fail(str(error), pytrace=False)
