"""Real robocloud processes on loopback for system tests: IaaS, simulator, their logs."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx

import waiting
from loopback_ports import free_port

API_KEY = "test-key"
HEADERS = {"Authorization": f"Bearer {API_KEY}"}


# Flags that turn a cloud's load shedding off (a 503 for new requests when too
# many wait): for tests that send bursts to check something else.
NO_SHEDDING = ["--busy-after", "3600", "--max-waiting", "1000000"]
FINAL_STATES = ("completed", "failed", "rejected", "canceled")


def wait_until(predicate: Callable[[], Any], timeout: float, what: str,
               every: float = 0.05) -> Any:
    """``waiting.wait_until``, a server not answering yet (a transport error) a false answer."""
    return waiting.wait_until(predicate, timeout, what, every, ignore=(httpx.TransportError,))


@dataclass
class Cloud:
    """One cloud: its IaaS process and its simulator process."""

    name: str
    workdir: Path
    store_url: str
    robots: int
    speedup: float
    http_port: int = field(default_factory=free_port)
    zenoh_port: int = field(default_factory=free_port)
    seed: int = 0
    churn: bool = False
    peers: list[str] = field(default_factory=list)  # other clouds' Zenoh endpoints
    iaas_args: list[str] = field(default_factory=list)  # more flags for `robocloud iaas`
    sim_args: list[str] = field(default_factory=list)  # more flags for `robocloud sim`
    iaas: subprocess.Popen[bytes] | None = None
    sim: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.http_port}"

    @property
    def zenoh(self) -> str:
        return f"tcp/127.0.0.1:{self.zenoh_port}"

    def client(self) -> httpx.Client:
        return httpx.Client(base_url=self.url, headers=HEADERS, timeout=10.0)

    def start_iaas(self) -> None:
        self.launch_iaas()
        self.wait_for_iaas()

    def launch_iaas(self) -> None:
        """Start the IaaS process without waiting for it (``wait_for_iaas``)."""
        log = open(self.workdir / f"{self.name}-iaas.log", "ab")  # noqa: SIM115
        env = {**os.environ, "ROBOCLOUD_API_KEYS": f"tests={API_KEY}"}
        self.iaas = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "robocloud.cli.main",
                "iaas",
                "--cloud",
                self.name,
                "--listen",
                f"127.0.0.1:{self.http_port}",
                "--zenoh",
                self.zenoh,
                "--store",
                self.store_url,
                "--time-scale",
                str(self.speedup),
                "--log-level",
                "warning",
                *[arg for peer in self.peers for arg in ("--peer", peer)],
                *self.iaas_args,
            ],
            stdout=log,
            stderr=subprocess.STDOUT,
            cwd=self.workdir,
            env=env,
        )

    def wait_for_iaas(self) -> None:
        # A bound, not a timing claim: on two cores shared with other work an
        # IaaS took up to 23 s to answer its first /healthz (it imports and
        # forks its selection workers first).
        wait_until(
            lambda: httpx.get(f"{self.url}/healthz", timeout=1).status_code == 200,
            60,
            f"{self.name}'s IaaS to answer",
        )

    def start_sim(self) -> None:
        if self.robots == 0:
            return
        log = open(self.workdir / f"{self.name}-sim.log", "ab")  # noqa: SIM115
        command = [
            sys.executable,
            "-m",
            "robocloud.cli.main",
            "sim",
            "--cloud",
            self.name,
            "--robots",
            str(self.robots),
            "--connect",
            self.zenoh,
            "--speedup",
            str(self.speedup),
            "--seed",
            str(self.seed),
        ]
        if not self.churn:
            command.append("--no-churn")
        command += self.sim_args
        self.sim = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, cwd=self.workdir)

    def wait_for_robots(self, count: int | None = None, timeout: float = 20) -> None:
        count = self.robots if count is None else count
        with self.client() as client:
            wait_until(
                # X-Total-Count: every robot, whatever the size of a page.
                lambda: int(client.get("/v1/robots", params={"limit": 1}).headers[
                    "X-Total-Count"]) >= count,
                timeout,
                f"{count} robots of {self.name} to report",
            )

    def router_refusals(self) -> dict[tuple[str, str], float]:
        """robocloud_router_refusals of the IaaS's /metrics: (party, message) -> count."""
        with self.client() as client:
            text = client.get("/metrics").text
        counts: dict[tuple[str, str], float] = {}
        for line in text.splitlines():
            if line.startswith("robocloud_router_refusals_total{"):
                labels, value = line.removeprefix("robocloud_router_refusals_total").rsplit(" ", 1)
                found = dict(
                    pair.split("=", 1) for pair in labels.strip("{}").split(",") if "=" in pair
                )
                key = (found["party"].strip('"'), found["message"].strip('"'))
                counts[key] = float(value)
        return counts

    def start(self) -> Cloud:
        self.start_iaas()
        self.start_sim()
        self.wait_for_robots()
        return self

    def kill_iaas(self) -> None:
        assert self.iaas is not None
        self.iaas.send_signal(signal.SIGKILL)
        self.iaas.wait(10)

    def stop(self) -> None:
        for process in (self.sim, self.iaas):
            if process is not None and process.poll() is None:
                process.terminate()
        for process in (self.sim, self.iaas):
            if process is not None:
                try:
                    process.wait(10)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait(5)

    def settle(self) -> None:
        """After a test on a shared cloud: its IaaS running, no request open, every robot free.

        A test may have killed the IaaS (it starts again, same port and store);
        its requests still open are canceled.
        """
        if self.iaas is None or self.iaas.poll() is not None:
            self.start_iaas()
        with self.client() as client:
            for request in client.get("/v1/requests", params={"limit": 200}).json()["items"]:
                if request["state"] not in FINAL_STATES:
                    client.post(f"/v1/requests/{request['id']}/cancel")
            wait_until(
                lambda: all(r["request"] is None for r in client.get("/v1/robots").json()),
                30,
                f"{self.name}'s robots to be free",
            )

    def fault(self, robot: str, fault: str, security: Any = None,
              session: Any = None) -> dict[str, Any]:
        """Inject a fault into a simulated robot over the cloud's Zenoh router.

        ``security``: how to join a router with TLS (the cloud's own certificate).
        ``session``: a client session already open to the router (left open), for a
        fault that must land within tenths of a second; else one is opened for it.
        """
        from robocloud.fleet import open_client

        own = session is None
        if own:
            session = open_client([self.zenoh], timeout=5.0, security=security)
        try:
            payload = json.dumps({"fault": fault, "robot": robot})
            for _ in range(50):
                replies = list(
                    session.get(f"robocloud/{self.name}/sim/control", payload=payload, timeout=2.0)
                )
                oks = [r.ok for r in replies if r.ok is not None]
                if oks:
                    answer: dict[str, Any] = json.loads(oks[0].payload.to_string())
                    return answer
                time.sleep(0.1)  # routes not known yet
            raise AssertionError("the simulator did not answer the fault")
        finally:
            if own:
                session.close()


def start_clouds(
    tmp_path: Path,
    names: Sequence[str],
    robots: int,
    speedup: float,
    *,
    chain: bool = False,
    iaas_args: Callable[[str], list[str]] = lambda name: [],
    sim_args: Callable[[str], list[str]] = lambda name: [],
    robots_at: Callable[[str], int] | None = None,
    together: bool = False,
) -> list[Cloud]:
    """Start one cloud per name, joined, and wait until the first sees them all.

    Full mesh, or a chain: a <- b <- c (c reaches a only through b). Each
    cloud's extra flags come from ``iaas_args(name)`` and ``sim_args(name)``;
    ``robots_at(name)``, when given, is its number of robots instead of ``robots``.
    ``together``: the IaaSs are started at once, then waited for (a router
    joins a peer that listens later by trying again), instead of one cloud
    after the other.
    """
    clouds: list[Cloud] = []
    for i, name in enumerate(names):
        cloud = Cloud(
            name,
            tmp_path,
            f"sqlite:///{tmp_path / f'{name}.db'}",
            robots=robots if robots_at is None else robots_at(name),
            speedup=speedup,
            seed=i,
            iaas_args=iaas_args(name),
            sim_args=sim_args(name),
        )
        cloud.peers = [clouds[-1].zenoh] if chain and clouds else [c.zenoh for c in clouds]
        clouds.append(cloud)
    try:
        if together:
            start_together(clouds)
        else:
            for cloud in clouds:
                cloud.start()
        with clouds[0].client() as client:
            wait_until(
                lambda: [c["cloud"] for c in client.get("/v1/clouds").json()] == sorted(names),
                20,
                f"{len(names)} clouds in the federation",
            )
    except BaseException:
        for cloud in clouds:
            cloud.stop()
        raise
    return clouds


def start_together(clouds: Sequence[Cloud]) -> None:
    """Start every cloud's IaaS at once, each simulator once its IaaS answers (its
    connect timeout runs from its start), then wait until each IaaS sees its robots."""
    for cloud in clouds:
        cloud.launch_iaas()
    for cloud in clouds:
        cloud.wait_for_iaas()
        cloud.start_sim()
    for cloud in clouds:
        cloud.wait_for_robots()


def follow(
    client: httpx.Client,
    request_id: str,
    until: Callable[[dict[str, Any]], bool],
    timeout: float,
    what: str,
) -> dict[str, Any]:
    def check() -> dict[str, Any] | None:
        body: dict[str, Any] = client.get(f"/v1/requests/{request_id}").json()
        return body if until(body) else None

    result: dict[str, Any] = wait_until(check, timeout, what, every=0.1)
    return result


def grabber_task(client: httpx.Client) -> tuple[dict[str, Any], set[str]]:
    """A task that needs every idle grabber the federation shows, and their clouds."""
    robots = client.get("/v1/robots", params={"scope": "federation"}).json()
    # Battery 50% or more: enough for any trip across the forest and back to work.
    grabbers = [
        r
        for r in robots
        if r["status"] == "idle" and "grabber" in r["capabilities"] and r["battery"] >= 50.0
    ]
    task = {
        "location": [1000.0, 1000.0],
        "actuating": {"grabber": len(grabbers)},
        "max_robots": len(grabbers),
        "max_cost": 100_000.0,
        "max_time": 100_000.0,
        "min_battery": 50.0,
        "priority": "time",
    }
    return task, {r["cloud"] for r in grabbers}
