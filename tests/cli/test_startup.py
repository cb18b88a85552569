"""Starting a command: every mistake is one sentence and an exit code, before anything is opened.

In-process (``main([...])``) for the sentences and codes; a few real processes
for what only a process shows: no traceback, exit code, a clean stop on SIGTERM.
"""

from __future__ import annotations

import math
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from robocloud.cli import main as cli_main
from robocloud.cli.main import main

PG_DOWN = "postgresql+psycopg://robocloud:s3cret@127.0.0.1:1/robots"


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
    return port


@pytest.fixture
def busy_port() -> Iterator[int]:
    """A port something else listens on."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        sock.listen()
        yield sock.getsockname()[1]


def iaas(*extra: str, store: str = "memory://") -> list[str]:
    return [
        "iaas",
        "--cloud",
        "cloud-t",
        "--listen",
        f"127.0.0.1:{free_port()}",
        "--zenoh",
        f"tcp/127.0.0.1:{free_port()}",
        "--store",
        store,
        *extra,
    ]


def one_sentence(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    assert out == ""
    assert err.startswith("robocloud: ") and err.endswith(".\n"), err
    assert err.count("\n") == 1, err
    assert "Traceback" not in err
    return code, err


# --- robocloud iaas: the store ----------------------------------------------------


@pytest.mark.parametrize(
    ("url", "shown"),
    [
        ("mysql://robocloud:s3cret@db/robots", "'mysql://robocloud:***@db/robots'"),
        ("postgresql+asyncpg://u:s3cret@db/r", "'postgresql+asyncpg://u:***@db/r'"),
        ("sqlite:///:memory:", "'sqlite:///:memory:'"),
        ("var/cloud.db", "'var/cloud.db'"),
        ("", None),  # empty: the default store, var/cloud-t.db (not reached: the port is bad)
    ],
)
def test_a_store_url_of_no_supported_kind_is_exit_2(
    capsys: pytest.CaptureFixture[str], url: str, shown: str | None, tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.chdir(tmp_path)
    if shown is None:
        code, err = one_sentence(capsys, *iaas("--offline-after", "0", store=url))
        assert code == 2 and "--offline-after" in err
        assert not (tmp_path / "var").exists()  # checked before var/ is made
        return
    code, err = one_sentence(capsys, *iaas(store=url))
    assert code == 2
    assert f"store URL {shown} is not a supported database URL" in err
    assert "s3cret" not in err


def test_a_missing_sqlite_folder_is_exit_2_and_is_not_created(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    folder = tmp_path / "no" / "such"
    code, err = one_sentence(capsys, *iaas(store=f"sqlite:///{folder / 'cloud.db'}"))
    assert code == 2
    assert f"the folder {folder} of the store" in err and "does not exist" in err
    assert not (tmp_path / "no").exists()


def test_a_sqlite_path_that_is_a_folder_is_exit_2(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    code, err = one_sentence(capsys, *iaas(store=f"sqlite:///{tmp_path}"))
    assert code == 2 and "is a folder" in err


def test_an_unreachable_postgresql_is_exit_1_without_the_password(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code, err = one_sentence(capsys, *iaas(store=PG_DOWN))
    assert code == 1
    assert "Cannot use the store at postgresql+psycopg://robocloud:***@127.0.0.1:1/robots" in err
    assert "s3cret" not in err


def test_the_default_store_makes_var_and_nothing_else(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    busy_port: int,
) -> None:
    # Zenoh's port is taken: the IaaS stops after it opened its default store.
    monkeypatch.chdir(tmp_path)
    argv = iaas(store="")
    argv[argv.index("--zenoh") + 1] = f"tcp/127.0.0.1:{busy_port}"
    code, err = one_sentence(capsys, *argv)
    assert code == 2 and "cannot open a Zenoh session" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["var"]
    assert (tmp_path / "var" / "cloud-t.db").is_file()


# --- robocloud iaas: the other arguments, all before anything is opened -----------


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--cloud", "a/b"], ["--cloud 'a/b' cannot be used in a Zenoh key"]),
        (["--cloud", ""], ["--cloud '' cannot be used"]),
        (["--time-scale", "0"], ["--time-scale must be more than 0"]),
        (["--time-scale", "nan"], ["--time-scale must be more than 0"]),
        (["--offline-after", "-1"], ["--offline-after must be more than 0"]),
        (["--busy-after", "0"], ["--busy-after must be more than 0, not 0.0."]),
        (["--busy-after", "nan"], ["--busy-after must be more than 0"]),
        (["--max-waiting", "0"], ["--max-waiting must be 1 to 1000000, not 0."]),
        (["--zenoh", "bogus"], ["--zenoh 'bogus' is not a Zenoh endpoint"]),
        (["--peer", "tcp127.0.0.1"], ["--peer 'tcp127.0.0.1' is not a Zenoh endpoint"]),
        (["--trust", "x*"], ["--trust 'x*' cannot be used"]),
        (["--api-key", "nokey"], ["'nokey' is not one"]),
        (["--tls-ca", "/no/such/ca.pem"], ["/no/such/ca.pem"]),
        (["--listen", "nohost.invalid:8101"], ["--listen nohost.invalid:8101"]),
    ],
)
def test_a_bad_argument_is_exit_2_and_opens_nothing(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, extra: list[str], words: list[str]
) -> None:
    store = tmp_path / "cloud.db"
    code, err = one_sentence(capsys, *iaas(*extra, store=f"sqlite:///{store}"))
    assert code == 2
    for word in words:
        assert word in err
    assert not store.exists()


def test_bad_api_keys_in_the_environment_are_exit_2(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("ROBOCLOUD_API_KEYS", "wildfire")
    code, err = one_sentence(capsys, *iaas())
    assert code == 2 and "ROBOCLOUD_API_KEYS" in err


def test_an_http_port_in_use_is_exit_1(
    capsys: pytest.CaptureFixture[str], busy_port: int, tmp_path: Path
) -> None:
    store = tmp_path / "cloud.db"
    argv = iaas(store=f"sqlite:///{store}")
    argv[argv.index("--listen") + 1] = f"127.0.0.1:{busy_port}"
    code, err = one_sentence(capsys, *argv)
    assert code == 1
    assert f"cannot listen on 127.0.0.1:{busy_port}: address already in use." in err
    assert not store.exists()  # the port is bound before the store is opened


# --- robocloud sim and robocloud wildfire -----------------------------------------


@pytest.mark.parametrize(
    ("extra", "word"),
    [
        (["--robots", "0"], "--robots must be at least 1"),
        (["--speedup", "0"], "--speedup must be more than 0"),
        (["--speedup", "nan"], "--speedup must be more than 0"),
        (["--connect-timeout", "-1"], "--connect-timeout must be 0 or more"),
        (["--seed", "-1"], "--seed must be at least 0"),
        (["--cloud", "a b "], "--cloud 'a b ' cannot be used"),
        (["--connect", "nowhere"], "--connect 'nowhere' is not a Zenoh endpoint"),
        (["--tls-ca", "/no/such/ca.pem"], "/no/such/ca.pem"),
    ],
)
def test_the_simulator_checks_its_arguments_before_it_connects(
    capsys: pytest.CaptureFixture[str], extra: list[str], word: str
) -> None:
    argv = ["sim", "--cloud", "cloud-t", "--connect", "tcp/127.0.0.1:1", *extra]
    code, err = one_sentence(capsys, *argv)
    assert code == 2 and word in err
    assert "simulating" not in err  # it never got to start


def test_wildfire_on_a_port_in_use_is_exit_1(
    capsys: pytest.CaptureFixture[str], busy_port: int
) -> None:
    code, err = one_sentence(
        capsys, "wildfire", "--iaas", "http://127.0.0.1:1", "--listen", f"127.0.0.1:{busy_port}"
    )
    assert code == 1 and f"cannot listen on 127.0.0.1:{busy_port}" in err


@pytest.mark.parametrize("timeout", ["0", "nan", "-3"])
def test_wildfire_checks_its_timeout(capsys: pytest.CaptureFixture[str], timeout: str) -> None:
    code, err = one_sentence(
        capsys, "wildfire", "--iaas", "http://127.0.0.1:1", "--timeout", timeout
    )
    assert code == 2 and "--timeout must be more than 0" in err


# --- what nobody foresaw ----------------------------------------------------------


def test_an_unexpected_error_is_one_sentence_and_debug_shows_the_traceback(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken(_: object) -> int:
        raise RuntimeError("the flux capacitor is empty\nsecond line")

    monkeypatch.setattr(cli_main, "scenario_command", broken)
    code, err = one_sentence(capsys, "scenario", "wildfire")
    assert code == 1
    assert err == (
        "robocloud: scenario stopped on an unexpected RuntimeError: the flux capacitor is "
        "empty; run it again with --log-level debug to see where.\n"
    )
    assert main(["scenario", "wildfire", "--log-level", "debug"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("Traceback (most recent call last):")
    assert err.endswith("to see where.\n")


def test_a_store_error_with_debug_shows_the_traceback_then_the_sentence(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(iaas("--log-level", "debug", store=PG_DOWN)) == 1
    err = capsys.readouterr().err
    assert "Traceback (most recent call last):" in err
    assert err.splitlines()[-1].startswith("robocloud: Cannot use the store at")


# --- real processes ----------------------------------------------------------------


def robocloud(*argv: str, **kwargs: object) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "robocloud.cli.main", *argv],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "ROBOCLOUD_API_KEYS": "tests=k"},
        **kwargs,  # type: ignore[call-overload]
    )


@pytest.mark.parametrize(
    ("store", "code", "words"),
    [
        (PG_DOWN, 1, "Cannot use the store at postgresql+psycopg://robocloud:***@"),
        ("sqlite:////nonexistent-robocloud/x/cloud.db", 2, "/nonexistent-robocloud/x"),
    ],
)
def test_the_process_says_one_sentence_and_exits(store: str, code: int, words: str) -> None:
    process = robocloud(*iaas(store=store))
    out, err = process.communicate(timeout=60)
    assert process.returncode == code
    assert (out, err.count("\n")) == ("", 1), err
    assert words in err and "Traceback" not in err and "s3cret" not in err
    assert not Path("/nonexistent-robocloud").exists()


def descendants(pid: int) -> set[int]:
    """The processes under ``pid`` (children, their children, ...), from /proc."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as stat:
                    parent = int(stat.read().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue  # ended meanwhile
            children.setdefault(parent, []).append(int(entry))
    found: set[int] = set()
    todo = [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            found.add(child)
            todo.append(child)
    return found


def wait_for_selection_workers(pid: int) -> set[int]:
    """The IaaS's helper processes once its two selection workers run (asserted)."""
    deadline = time.monotonic() + 30
    while True:
        helpers = descendants(pid)
        workers = [p for p in helpers if b"forkserver" in _cmdline(p)]
        if len(workers) >= 3:  # the fork server and the two workers forked from it
            return helpers
        assert time.monotonic() < deadline, f"no selection workers under {pid}: {helpers}"
        time.sleep(0.1)


def _cmdline(pid: int) -> bytes:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as cmdline:
            return cmdline.read()
    except OSError:
        return b""


def assert_all_ended(pids: set[int], within: float = 10.0) -> None:
    deadline = time.monotonic() + within
    alive = pids
    while alive and time.monotonic() < deadline:
        alive = {p for p in alive if _cmdline(p)}  # a zombie has no command line either
        time.sleep(0.1)
    assert not alive, f"processes left behind: {[_cmdline(p)[:120] for p in alive]}"


@pytest.mark.slow
def test_a_killed_iaas_leaves_no_selection_process_behind(tmp_path: Path) -> None:
    """SIGKILL gives the IaaS no chance to close its pool: its helpers end on their own."""
    port = free_port()
    argv = iaas(store=f"sqlite:///{tmp_path / 'cloud.db'}")
    argv[argv.index("--listen") + 1] = f"127.0.0.1:{port}"
    process = robocloud(*argv, cwd=tmp_path)
    try:
        helpers = wait_for_selection_workers(process.pid)
    finally:
        process.kill()
        process.communicate(timeout=30)
    assert_all_ended(helpers)


@pytest.mark.slow
@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGINT])
def test_the_iaas_serves_and_stops_cleanly_on_a_signal(tmp_path: Path, stop: int) -> None:
    port = free_port()
    argv = iaas(store=f"sqlite:///{tmp_path / 'cloud.db'}")
    argv[argv.index("--listen") + 1] = f"127.0.0.1:{port}"
    process = robocloud(*argv, "--log-level", "info", cwd=tmp_path)
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                health = httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=1).json()
                break
            except httpx.TransportError:
                assert process.poll() is None, process.communicate()
                assert time.monotonic() < deadline, "the IaaS did not answer"
                time.sleep(0.1)
        assert health["cloud"] == "cloud-t" and health["store"] == "sqlite"
        helpers = wait_for_selection_workers(process.pid)
        process.send_signal(stop)
        _, err = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 0, err
    assert_all_ended(helpers)
    assert "Traceback" not in err
    assert f"serving http://127.0.0.1:{port}/v1" in err
    assert (tmp_path / "cloud.db").is_file()
    assert not math.isnan(health["time_scale"])


def test_load_shedding_flags_reach_the_settings() -> None:
    from robocloud.cli.iaas_command import iaas_settings
    from robocloud.cli.main import build_parser

    default = iaas_settings(build_parser().parse_args(iaas()))
    assert (default.busy_after, default.max_waiting) == (0.5, 1000)
    given = iaas_settings(
        build_parser().parse_args(iaas("--busy-after", "0.1", "--max-waiting", "40"))
    )
    assert (given.busy_after, given.max_waiting) == (0.1, 40)
