"""The demo's log files rotate at a size bound and take everything a process writes."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from robocloud.cli.logfile import BACKUPS, MAX_BYTES, RotatingLog


def test_the_documented_bound() -> None:
    assert (MAX_BYTES, BACKUPS) == (5 * 1024 * 1024, 3)  # README: 5 MB and three older files


def test_a_process_output_rotates_within_the_bound(tmp_path: Path) -> None:
    path = tmp_path / "wildfire.log"
    log = RotatingLog(path, max_bytes=2000, backups=3)
    # 400 lines of 50 bytes on stdout and stderr: 20 kB, ten times one file.
    script = (
        "import sys\n"
        "for i in range(200):\n"
        "    print(f'out {i:04d} ' + 'x' * 40)\n"
        "    print(f'err {i:04d} ' + 'y' * 40, file=sys.stderr)\n"
        "print('100% done')\n"
    )
    process = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT)
    assert process.stdout is not None
    log.follow(process.stdout, "test-copy")
    assert process.wait(10) == 0
    log.close(timeout=10)
    files = sorted(tmp_path.iterdir())
    assert [f.name for f in files] == [
        "wildfire.log", "wildfire.log.1", "wildfire.log.2", "wildfire.log.3"
    ]
    assert all(f.stat().st_size <= 2000 for f in files)
    # The newest lines are in the file, whole, in order; "%" is not a format.
    lines = path.read_text().splitlines()
    assert lines[-1] == "100% done" and lines[-2] == "err 0199 " + "y" * 40
    older = (tmp_path / "wildfire.log.1").read_text().splitlines()
    assert all(line.startswith(("out ", "err ")) and len(line) == 49 for line in older)


def test_a_restarted_process_appends_to_the_same_file(tmp_path: Path) -> None:
    path = tmp_path / "cloud-a-iaas.log"
    log = RotatingLog(path)
    for word in ("first", "second"):
        process = subprocess.Popen([sys.executable, "-c", f"print({word!r})"],
                                   stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        assert process.stdout is not None
        log.follow(process.stdout, word).join(10)  # this copy ends with its process
        process.wait(10)
    log.close(timeout=10)
    assert path.read_text().splitlines() == ["first", "second"]
