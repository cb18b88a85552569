"""One IaaS and one simulator as real processes on loopback, as ``make run`` starts them.

The start-up that the fleet-size and memory benchmarks (``fleet.py``,
``memory.py``) share: a fresh ``robocloud iaas`` on its own SQLite file,
waited for until ``/healthz`` answers; then a ``robocloud sim`` whose robots
are waited for until the IaaS counts them all (``GIVE_UP`` seconds at most).
Each process logs to a file of ``workdir``; every process is stopped at the end.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx

from benchmarks.service import _port, terminate_all

CLOUD = "cloud-a"
GIVE_UP = 120.0  # seconds to wait for a fleet to join


@dataclass
class Joined:
    """A simulator started, and how many of its robots the IaaS counted, after how long."""

    sim: subprocess.Popen[bytes]
    seen: int
    seconds: float


@dataclass
class OneCloud:
    name: str  # the run's name: its store and logs are <workdir>/<name>...
    workdir: Path
    url: str
    endpoint: str  # the IaaS's Zenoh router
    key: str  # an API key of the IaaS
    env: dict[str, str]
    client: httpx.Client
    iaas: subprocess.Popen[bytes]
    processes: list[subprocess.Popen[bytes]]

    def robots(self) -> int:
        """The robots the IaaS counts now (``/healthz``), -1 while it does not answer."""
        return count(self.client)

    def start_sim(self, robots: int, *flags: str) -> Joined:
        """A simulator of ``robots`` robots (no churn, with ``flags``), waited for
        until the IaaS counts every robot, the simulator exits or ``GIVE_UP``."""
        log = open(self.workdir / f"{self.name}-sim.log", "wb")  # noqa: SIM115
        started = time.monotonic()
        sim = subprocess.Popen(
            [*_robocloud(), "sim", "--cloud", CLOUD, "--robots", str(robots),
             "--connect", self.endpoint, "--no-churn", *flags],
            stdout=log, stderr=subprocess.STDOUT, env=self.env)  # fmt: skip
        self.processes.append(sim)
        seen = 0
        while time.monotonic() - started < GIVE_UP and sim.poll() is None:
            seen = max(seen, self.robots())
            if seen >= robots:
                break
            time.sleep(0.25)
        return Joined(sim, seen, time.monotonic() - started)


def count(client: httpx.Client) -> int:
    try:
        answer = client.get("/healthz", timeout=5)
    except httpx.TransportError:
        return -1
    return int(answer.json()["robots"]) if answer.status_code == 200 else -1


def _robocloud() -> list[str]:
    return [sys.executable, "-m", "robocloud.cli.main"]


@contextlib.contextmanager
def one_cloud(
    workdir: Path, name: str, *, start_within: float, src: Path | None = None
) -> Iterator[OneCloud]:
    """A fresh IaaS (store ``<workdir>/<name>.db``), answering within ``start_within``
    seconds; ``src``: run the processes from that source tree."""
    key = secrets.token_urlsafe(12)
    env = {**os.environ, "ROBOCLOUD_API_KEYS": f"bench={key}"}
    if src is not None:
        env["PYTHONPATH"] = f"{src}{os.pathsep}{env.get('PYTHONPATH', '')}"
    http, zport = _port(), _port()
    url, endpoint = f"http://127.0.0.1:{http}", f"tcp/127.0.0.1:{zport}"
    db = workdir / f"{name}.db"
    for leftover in workdir.glob(f"{name}.db*"):
        leftover.unlink()
    processes: list[subprocess.Popen[bytes]] = []
    try:
        with httpx.Client(base_url=url) as client:
            log = open(workdir / f"{name}-iaas.log", "wb")  # noqa: SIM115
            iaas = subprocess.Popen(
                [*_robocloud(), "iaas", "--cloud", CLOUD, "--listen", f"127.0.0.1:{http}",
                 "--zenoh", endpoint, "--store", f"sqlite:///{db}", "--log-level", "warning"],
                stdout=log, stderr=subprocess.STDOUT, env=env)  # fmt: skip
            processes.append(iaas)
            deadline = time.monotonic() + start_within
            while count(client) < 0:
                if time.monotonic() > deadline or iaas.poll() is not None:
                    raise RuntimeError(f"the IaaS did not start; see {log.name}")
                time.sleep(0.1)
            yield OneCloud(name, workdir, url, endpoint, key, env, client, iaas, processes)
    finally:
        terminate_all(processes, wait=15)
