"""``make run``: the whole system on this machine, with simulated robots.

Starts three clouds (``cloud-a``, ``cloud-b``, ``cloud-c``; 1,000 simulated
robots between them, as in the thesis's scenario), each with its IaaS (HTTP
API, Zenoh router, SQLite store under ``var/``) and its fleet simulator, the
routers joined over loopback (each cloud connects to the ones before it);
prints where the API is and the key to use, and stops everything on Ctrl-C
(or SIGTERM), leaving no process behind. A request sent to any cloud is
served by the robots of all of them.
"""

from __future__ import annotations

import argparse
import os
import secrets
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import httpx

from robocloud.sim.scenario import cloud_names


@dataclass
class Member:
    cloud: str
    http_port: int
    zenoh_port: int
    robots: int

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.http_port}"

    @property
    def zenoh(self) -> str:
        return f"tcp/127.0.0.1:{self.zenoh_port}"


def split(total: int, parts: int) -> list[int]:
    return [total // parts + (1 if i < total % parts else 0) for i in range(parts)]


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="make run", description=__doc__)
    parser.add_argument("--clouds", type=int, default=3, help="how many clouds (default 3)")
    parser.add_argument(
        "--robots", type=int, default=1000, help="simulated robots in all (default 1000)"
    )
    parser.add_argument(
        "--speedup", type=float, default=10.0, help="robot time per wall second (default 10)"
    )
    parser.add_argument(
        "--http-port",
        type=int,
        default=8101,
        help="the first cloud's HTTP port; the next clouds count up",
    )
    parser.add_argument(
        "--zenoh-port",
        type=int,
        default=7447,
        help="the first cloud's Zenoh port; the next clouds count up",
    )
    parser.add_argument("--var", default="var", help="where stores and logs go (default var/)")
    parser.add_argument(
        "--wildfire-port",
        type=int,
        default=8000,
        help="the Wildfire Suppression Application's port (default 8000)",
    )
    args = parser.parse_args(argv)
    if not 1 <= args.clouds <= 26 or args.robots < args.clouds or args.speedup <= 0:
        parser.error("need 1 to 26 clouds, at least one robot per cloud, a positive speedup")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    var = Path(args.var)
    var.mkdir(parents=True, exist_ok=True)
    key = os.environ.get("ROBOCLOUD_DEMO_KEY") or secrets.token_urlsafe(18)
    env = {**os.environ, "ROBOCLOUD_API_KEYS": f"demo={key}"}
    members = [
        Member(name, args.http_port + i, args.zenoh_port + i, n)
        for i, (name, n) in enumerate(
            zip(cloud_names(args.clouds), split(args.robots, args.clouds), strict=True)
        )
    ]
    processes: list[subprocess.Popen[bytes]] = []
    names: dict[int, str] = {}  # pid -> what it is, for messages
    stopping = False

    def stop(*_: object) -> None:
        nonlocal stopping
        stopping = True

    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    python = [sys.executable, "-m", "robocloud.cli.main"]
    try:
        for i, m in enumerate(members):
            log = open(var / f"{m.cloud}-iaas.log", "ab")  # noqa: SIM115
            processes.append(
                subprocess.Popen(
                    [
                        *python,
                        "iaas",
                        "--cloud",
                        m.cloud,
                        "--listen",
                        f"127.0.0.1:{m.http_port}",
                        "--zenoh",
                        m.zenoh,
                        "--store",
                        f"sqlite:///{var / f'{m.cloud}.db'}",
                        "--time-scale",
                        str(args.speedup),
                        "--log-level",
                        "warning",
                        *[arg for other in members[:i] for arg in ("--peer", other.zenoh)],
                    ],
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    env=env,
                    start_new_session=True,
                )
            )
            names[processes[-1].pid] = f"{m.cloud}'s IaaS"
        for m in members:
            _wait_healthy(m, processes)
        for i, m in enumerate(members):
            log = open(var / f"{m.cloud}-sim.log", "ab")  # noqa: SIM115
            processes.append(
                subprocess.Popen(
                    [
                        *python,
                        "sim",
                        "--cloud",
                        m.cloud,
                        "--robots",
                        str(m.robots),
                        "--connect",
                        m.zenoh,
                        "--speedup",
                        str(args.speedup),
                        "--seed",
                        str(i),
                    ],
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    start_new_session=True,
                )
            )
            names[processes[-1].pid] = f"{m.cloud}'s simulator"
        log = open(var / "wildfire.log", "ab")  # noqa: SIM115
        processes.append(
            subprocess.Popen(
                [
                    *python,
                    "wildfire",
                    "--iaas",
                    members[0].url,
                    "--listen",
                    f"127.0.0.1:{args.wildfire_port}",
                ],
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
                env={**os.environ, "ROBOCLOUD_WILDFIRE_API_KEY": key},
            )
        )
        names[processes[-1].pid] = "the Wildfire Suppression Application"
        print(_banner(members, key, args.speedup, var, args.wildfire_port), flush=True)
        while not stopping:
            for process in processes:
                if process.poll() is not None:
                    print(
                        f"{names[process.pid]} stopped (exit {process.returncode}); "
                        f"see the logs in {var}/. Stopping.",
                        file=sys.stderr,
                    )
                    return 1
            time.sleep(0.5)
        print("stopping...", file=sys.stderr)
        return 0
    finally:
        _stop_all(processes)


def _wait_healthy(member: Member, processes: list[subprocess.Popen[bytes]]) -> None:
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        if any(p.poll() is not None for p in processes):
            raise SystemExit(
                f"{member.cloud}'s IaaS did not start; see var/{member.cloud}"
                "-iaas.log (is the port in use?)"
            )
        try:
            if httpx.get(f"{member.url}/healthz", timeout=1).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    raise SystemExit(f"{member.cloud}'s IaaS did not answer on {member.url} within 30 s")


def _stop_all(processes: list[subprocess.Popen[bytes]]) -> None:
    for process in reversed(processes):
        if process.poll() is None:
            process.terminate()
    deadline = time.monotonic() + 10
    for process in processes:
        try:
            process.wait(max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def _banner(members: list[Member], key: str, speedup: float, var: Path, wildfire_port: int) -> str:
    lines = [
        "",
        "robocloud is running:",
        f"  Wildfire Suppression Application: http://127.0.0.1:{wildfire_port}/",
    ]
    for m in members:
        lines.append(
            f"  {m.cloud}: {m.robots} simulated robots, API {m.url}/v1 "
            f"(docs {m.url}/docs), Zenoh {m.zenoh}"
        )
    first = members[0]
    lines += [
        f"  API key: {key}   (application 'demo'; send it as 'Authorization: Bearer {key}')",
        f"  robots run {speedup:g}x faster than the clock; stores and logs are in {var}/",
        "",
        "Try:",
        f"  curl -s -H 'Authorization: Bearer {key}' {first.url}/v1/robots | head -c 300",
        f"  curl -s -H 'Authorization: Bearer {key}' -H 'Content-Type: application/json' \\",
        '    -d \'{"location": [1000, 1000], "sensing": {"sound": 1}, '
        '"actuating": {"grabber": 1}, "max_robots": 5, "max_cost": 500, '
        '"max_time": 900, "min_battery": 50, "priority": "time"}\' \\',
        f"    {first.url}/v1/requests",
        "",
        "Ctrl-C stops everything.",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
