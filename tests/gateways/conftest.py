"""The gateway's tests: one MQTT broker for all (``mosquitto``), topics of their own each."""

from __future__ import annotations

import secrets
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture
def interface() -> Iterator[str]:
    """Topics of this test alone, on a broker other tests may share."""
    yield f"uagv-test-{secrets.token_hex(4)}"
