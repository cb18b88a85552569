"""A real system on loopback for the browser tests: IaaSs, their simulated robots, the page.

Each part is a subprocess on free ports, with its log in the work folder; start-up
waits for ``/healthz``, for the robots to report, and for the wildfire server to
reach the IaaS; ``stop`` always ends every process it started.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import httpx

import waiting
from loopback_ports import free_port

API_KEY = "wildfire-test-key"
CHROMIUM_ARGS = [
    "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
]


def wait_until(predicate: Callable[[], Any], timeout: float, what: str,
               every: float = 0.1) -> Any:
    """``waiting.wait_until``, a server not answering yet (a transport error) a false answer."""
    return waiting.wait_until(predicate, timeout, what, every, ignore=(httpx.TransportError,))


@dataclass
class Cloud:
    name: str
    seed: int
    iaas_port: int = field(default_factory=free_port)
    zenoh_port: int = field(default_factory=free_port)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.iaas_port}"

    @property
    def zenoh(self) -> str:
        return f"tcp/127.0.0.1:{self.zenoh_port}"


@dataclass
class System:
    """``robocloud iaas`` + ``robocloud sim`` per cloud, and ``robocloud wildfire``.

    Several clouds form a federation (each IaaS peers with the ones before
    it); the wildfire server is given every cloud's IaaS, the first as home
    (``home_only`` gives it the first alone), and sees every robot.
    """

    workdir: Path
    clouds: int = 1
    robots: int = 60  # per cloud
    robot_counts: list[int] | None = None  # per cloud, when they differ
    speedup: float = 100.0
    seed: int = 0
    churn: bool = False
    home_only: bool = False
    wildfire_args: list[str] = field(default_factory=list)
    iaas_args: list[str] = field(default_factory=list)  # more flags for each `robocloud iaas`
    wildfire_port: int = field(default_factory=free_port)
    processes: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)
    logs: dict[str, IO[bytes]] = field(default_factory=dict)
    members: list[Cloud] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.members = [Cloud(f"cloud-{chr(ord('a') + i)}", self.seed + i)
                        for i in range(self.clouds)]

    def count(self, cloud: Cloud) -> int:
        if self.robot_counts is None:
            return self.robots
        return self.robot_counts[self.members.index(cloud)]

    @property
    def total(self) -> int:
        return sum(self.count(c) for c in self.members)

    @property
    def iaas_url(self) -> str:
        return self.members[0].url

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.wildfire_port}/"

    def iaas(self) -> httpx.Client:
        return httpx.Client(base_url=self.iaas_url, timeout=10.0,
                            headers={"Authorization": f"Bearer {API_KEY}"})

    def _start(self, name: str, argv: list[str], env: dict[str, str] | None = None) -> None:
        log = open(self.workdir / f"{name}.log", "ab")  # noqa: SIM115 - closed in stop()
        self.logs[name] = log
        self.processes[name] = subprocess.Popen(
            [sys.executable, "-m", *argv], stdout=log, stderr=subprocess.STDOUT,
            cwd=self.workdir, env={**os.environ, **(env or {})})

    def _check_alive(self) -> None:
        for name, process in self.processes.items():
            if process.poll() is not None:
                raise AssertionError(f"{name} exited with {process.returncode}:\n{self.log(name)}")

    def log(self, name: str) -> str:
        path = self.workdir / f"{name}.log"
        return path.read_text(errors="replace")[-3000:] if path.exists() else ""

    def start(self) -> System:
        for i, cloud in enumerate(self.members):
            peers = [arg for other in self.members[:i] for arg in ("--peer", other.zenoh)]
            self._start(f"{cloud.name}-iaas", [
                "robocloud.cli.main", "iaas", "--cloud", cloud.name,
                "--listen", f"127.0.0.1:{cloud.iaas_port}", "--zenoh", cloud.zenoh, *peers,
                "--store", f"sqlite:///{self.workdir / f'{cloud.name}.db'}",
                "--time-scale", str(self.speedup), "--log-level", "warning", *self.iaas_args,
            ], env={"ROBOCLOUD_API_KEYS": f"wildfire={API_KEY}"})
        for cloud in self.members:
            self._wait(f"{cloud.name}'s IaaS to answer /healthz", 60,
                       lambda url=cloud.url: httpx.get(f"{url}/healthz", timeout=1).status_code
                       == 200)
            self._start(f"{cloud.name}-sim", [
                "robocloud.cli.main", "sim", "--cloud", cloud.name, "--robots",
                str(self.count(cloud)), "--connect", cloud.zenoh, "--speedup", str(self.speedup),
                "--seed", str(cloud.seed), *([] if self.churn else ["--no-churn"]),
            ])
        iaas = [self.members[0]] if self.home_only else self.members
        self._start("wildfire", [
            "robocloud.wildfire.command", *[a for c in iaas for a in ("--iaas", c.url)],
            "--listen", f"127.0.0.1:{self.wildfire_port}", "--log-level", "warning",
            *self.wildfire_args,
        ], env={"ROBOCLOUD_WILDFIRE_API_KEY": API_KEY})
        total = self.total
        with self.iaas() as client:
            self._wait(f"{total} robots to report", 40, lambda: len(client.get(
                "/v1/robots", params={"scope": "federation"}).json()) >= total)
        self._wait("the wildfire server to reach the IaaS", 30,
                   lambda: httpx.get(f"{self.url}api/health", timeout=2).status_code == 200)
        return self

    def cloud(self, name: str) -> Cloud:
        return next(c for c in self.members if c.name == name)

    def freeze(self, part: str) -> None:
        """Stop a process dead (SIGSTOP): its sockets stay open, nothing answers.

        ``part`` is a cloud (its IaaS) or ``wildfire``."""
        self.processes[part if part == "wildfire" else f"{part}-iaas"].send_signal(signal.SIGSTOP)

    def thaw(self, part: str) -> None:
        self.processes[part if part == "wildfire" else f"{part}-iaas"].send_signal(signal.SIGCONT)

    def kill_cloud(self, cloud: str) -> None:
        """A cloud gone at once: its IaaS and its robots, killed."""
        for part in ("iaas", "sim"):
            process = self.processes[f"{cloud}-{part}"]
            process.send_signal(signal.SIGKILL)
            process.wait(10)

    def fault(self, cloud: str, robot: str, fault: str) -> dict[str, Any]:
        """Inject a fault into a simulated robot over its cloud's Zenoh router."""
        from robocloud.fleet import open_client

        session = open_client([self.cloud(cloud).zenoh], timeout=5.0)
        try:
            payload = json.dumps({"fault": fault, "robot": robot})
            for _ in range(50):
                replies = list(session.get(f"robocloud/{cloud}/sim/control", payload=payload,
                                           timeout=2.0))
                oks = [r.ok for r in replies if r.ok is not None]
                if oks:
                    answer: dict[str, Any] = json.loads(oks[0].payload.to_string())
                    return answer
                time.sleep(0.1)  # routes not known yet
            raise AssertionError("the simulator did not answer the fault")
        finally:
            session.close()

    def _wait(self, what: str, timeout: float, predicate: Callable[[], Any]) -> None:
        def alive_and(predicate: Callable[[], Any] = predicate) -> Any:
            self._check_alive()
            return predicate()

        wait_until(alive_and, timeout, what)

    def stop(self) -> None:
        for process in self.processes.values():
            if process.poll() is None:
                process.send_signal(signal.SIGCONT)  # a frozen process cannot end
                process.terminate()
        for process in self.processes.values():
            try:
                process.wait(10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(5)
        for log in self.logs.values():
            log.close()
