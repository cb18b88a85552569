"""The gateway's tests use the local Mosquitto (127.0.0.1:1883), each on topics of its own."""

from __future__ import annotations

import os
import secrets
import socket
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

MQTT_HOST = "127.0.0.1"
MQTT_PORT = int(os.environ.get("ROBOCLOUD_TEST_MQTT_PORT", "1883"))


@pytest.fixture(scope="session")
def mosquitto() -> tuple[str, int]:
    """The broker, or a failure that says how to start it (never a skip: CI must run these)."""
    try:
        with socket.create_connection((MQTT_HOST, MQTT_PORT), timeout=2):
            pass
    except OSError as error:
        pytest.fail(
            f"no MQTT broker at {MQTT_HOST}:{MQTT_PORT} ({error}); start Mosquitto "
            "(`mosquitto -d`, or `apt-get install mosquitto`).",
            pytrace=False,
        )
    return MQTT_HOST, MQTT_PORT


@pytest.fixture
def interface() -> Iterator[str]:
    """Topics of this test alone, on a broker other tests may share."""
    yield f"uagv-test-{secrets.token_hex(4)}"
