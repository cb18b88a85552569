"""Log lines that cannot be forged (robocloud.logs), and names that cannot carry controls."""

from __future__ import annotations

import logging
import subprocess
import sys
from collections.abc import Iterator

import pydantic
import pytest

from robocloud import logs
from robocloud.domain import Robot

FORGED = "x\n2026-12-02 04:30:00,000 cloud-a WARNING robocloud.iaas.home: cloud-b is back"


@pytest.fixture
def escaping() -> Iterator[None]:
    factory = logging.getLogRecordFactory()
    logs._installed = False
    logs.install()
    yield
    logging.setLogRecordFactory(factory)
    logs._installed = False


def test_a_forged_line_stays_on_its_own_line(
    escaping: None, caplog: pytest.LogCaptureFixture
) -> None:
    log = logging.getLogger("robocloud.test")
    with caplog.at_level(logging.INFO, "robocloud.test"):
        log.warning("refused a capability named %s", FORGED)
        log.info("%s", "a\rb\x00c\x1b[31m\u202egnp.exe\x85\u2028")
    forged, hidden = (record.getMessage() for record in caplog.records)
    assert "\n" not in forged
    assert forged == (
        "refused a capability named x\\n2026-12-02 04:30:00,000 cloud-a WARNING "
        "robocloud.iaas.home: cloud-b is back"
    )
    assert hidden == "a\\rb\\x00c\\x1b[31m\\u202egnp.exe\\x85\\u2028"
    assert len(caplog.text.strip().splitlines()) == 2  # one line per record


def test_every_command_installs_it() -> None:
    """Every command runs through robocloud.cli.exits.run, which installs the escape first."""
    script = (
        "import argparse, logging\n"
        "from robocloud.cli.exits import run\n"
        "run(lambda args: 0, argparse.Namespace())\n"
        "logging.basicConfig(format='%(message)s')\n"
        f"logging.getLogger('x').warning('%s', {FORGED!r})\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=60
    )
    assert done.stderr.strip().splitlines()[-1].startswith("x\\n2026-12-02"), done.stderr


@pytest.mark.parametrize(
    "name", ["a\u202eb", "a\u2066b", "a\u2069b", "a\x85b", "a\x9fb", "a\x7fb", "a\nb", "a\x00b"]
)
def test_names_with_controls_or_bidi_overrides_are_refused(name: str) -> None:
    robot = {
        "id": name, "cloud": "cloud-a", "position": [0.0, 0.0], "speed": 1.0,
        "battery": 50.0, "status": "idle", "travel_cost_per_m": 0.0, "capabilities": {},
    }  # fmt: skip
    with pytest.raises(pydantic.ValidationError, match="id"):
        Robot.model_validate(robot)
    assert Robot.model_validate({**robot, "id": "café-1"}).id == "café-1"
