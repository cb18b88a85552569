"""Debian's chromium for the browser tests: Playwright launches it, or the test fails saying why.

Playwright's own browser download cannot work here, so it drives the system's
chromium through ``executable_path``; ``tests/wildfire/ensure_chromium.sh``
installs it where it can (``make test`` runs it). Where it is missing or does
not start, a browser test fails, never skips (CI must run them), with one
sentence that says what to install.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

CHROMIUM = "/usr/bin/chromium"
INSTALL = "`sudo apt-get install chromium` (make test does it when it runs as root)"


def launch_chromium(playwright: Any, args: list[str]) -> Any:
    """The browser, or a failure of the test with what to install."""
    if not Path(CHROMIUM).exists():
        pytest.fail(f"The browser tests need Debian's chromium at {CHROMIUM}: install it with "
                    f"{INSTALL}.", pytrace=False)  # fmt: skip
    from playwright.sync_api import Error

    try:
        return playwright.chromium.launch(executable_path=CHROMIUM, args=args)
    except Error as error:
        first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        pytest.fail(f"{CHROMIUM} does not start ({first}): reinstall Debian's chromium with "
                    f"{INSTALL}.", pytrace=False)  # fmt: skip
