"""``make run``: the whole system on this machine, with simulated robots.

Why one long file: ``make run``'s whole life (the processes it plans, their
start, supervision and restarts, its banner) is one script a reader follows
from top to bottom; nothing else imports it.

Starts three clouds (``cloud-a``, ``cloud-b``, ``cloud-c``; 1,000 simulated
robots between them, as in the thesis's scenario), each with its IaaS (HTTP
API, Zenoh router, SQLite store under ``var/``) and its fleet simulator, the
routers joined over loopback (each cloud connects to the ones before it),
and the Wildfire Suppression Application at the first cloud; prints where
everything is and the key to use. A request sent to any cloud is served by
the robots of all of them.

A cloud may fail and come back while the rest goes on: when one of the
processes stops (``kill`` the pid the banner shows for a cloud's IaaS), the
demo says so and keeps the others running, so the federation can be watched
re-planning. It restarts what stopped on Enter (in a terminal), on the name of
a cloud and Enter (that cloud only), or on ``kill -USR1 <the demo's pid>``
(works without a terminal). It also prints the ``robocloud`` commands that
start the stopped processes by hand.

State: the stores and logs in ``var/`` are kept between runs (requests of an
earlier run are there, and unfinished ones resume); ``make reset`` empties it.
Ctrl-C (or SIGTERM) stops everything, leaving no process behind.
"""

from __future__ import annotations

import argparse
import os
import queue
import secrets
import shlex
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import httpx

from robocloud.cli.logfile import RotatingLog
from robocloud.sim.scenario import MAX_CLOUDS, cloud_names

WILDFIRE = "wildfire"
HEALTH_TIMEOUT_S = 30.0
ROOT = Path(__file__).resolve().parents[3]
NXT_BRICKS = ROOT / "examples" / "nxt" / "thesis-bricks.json"
NXT_ROBOTS = ("nxt-tribot", "nxt-base-1", "nxt-base-2")
NXT_OBSTACLES = ("10.3,10,0.15", "9.7,10,0.15")  # red, where the example request sends them


class NotStarted(Exception):
    """A part stopped or stayed silent while starting; the message says which and where to look."""


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


@dataclass
class Part:
    """One process of the demo: what it is, the group it restarts with, how to start it."""

    title: str  # "cloud-b's IaaS"
    group: str  # "cloud-b", or "wildfire"
    argv: list[str]  # after `robocloud`
    log: Path
    env: dict[str, str] = field(default_factory=dict)  # besides os.environ
    health: str | None = None  # a URL that answers 200 once it serves
    process: subprocess.Popen[bytes] | None = None
    reported: bool = False

    sink: RotatingLog | None = None  # the log file, opened at the first start

    def start(self) -> None:
        if self.sink is None:
            self.sink = RotatingLog(self.log)
        self.process = subprocess.Popen(
            [sys.executable, "-m", "robocloud.cli.main", *self.argv],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            env={**os.environ, **self.env},
            # Its own session: Ctrl-C in the terminal reaches the demo only,
            # which then stops every part in order.
            start_new_session=True,
        )
        assert self.process.stdout is not None
        self.sink.follow(self.process.stdout, f"log-{self.group}-{self.argv[0]}")
        self.reported = False

    @property
    def pid(self) -> int:
        return self.process.pid if self.process is not None else 0

    def stopped(self) -> bool:
        return self.process is None or self.process.poll() is not None

    def by_hand(self) -> str:
        """The shell command that starts this part, for an operator who'd rather."""
        robocloud = Path(sys.executable).with_name("robocloud")
        program = str(robocloud)
        if not robocloud.exists():
            program = f"{sys.executable} -m robocloud.cli.main"
        env = " ".join(f"{name}={shlex.quote(value)}" for name, value in self.env.items())
        return f"{env + ' ' if env else ''}{program} {shlex.join(self.argv)}"


def split(total: int, parts: int) -> list[int]:
    return [total // parts + (1 if i < total % parts else 0) for i in range(parts)]


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m robocloud.cli.demo",
        description="The whole system on this machine (make run): clouds, simulated robots, "
        "the Wildfire Suppression Application.",
    )
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
        "--nxt",
        action="store_true",
        help="add the thesis's three NXT robots to the first cloud: stand-in bricks "
        f"({NXT_BRICKS.relative_to(ROOT)}) behind the NXT gateway",
    )
    parser.add_argument(
        "--wildfire-port",
        type=int,
        default=8000,
        help="the Wildfire Suppression Application's port (default 8000)",
    )
    args = parser.parse_args(argv)
    if not 1 <= args.clouds <= MAX_CLOUDS:
        parser.error(f"--clouds must be between 1 and {MAX_CLOUDS}, not {args.clouds}")
    if args.robots < args.clouds:
        parser.error(f"--robots must be at least one per cloud ({args.clouds}), not {args.robots}")
    if not args.speedup > 0:
        parser.error(f"--speedup must be more than 0, not {args.speedup}")
    for flag, first, count in (
        ("--http-port", args.http_port, args.clouds),
        ("--zenoh-port", args.zenoh_port, args.clouds),
        ("--wildfire-port", args.wildfire_port, 1),
    ):
        if not 1 <= first <= 65536 - count:
            parser.error(f"{flag} {first}: the ports from it must be between 1 and 65535")
    return args


def plan(args: argparse.Namespace, key: str) -> tuple[list[Member], list[Part]]:
    """The clouds, and every process: each IaaS, each simulator, the page, in that order."""
    var = Path(args.var)
    members = [
        Member(name, args.http_port + i, args.zenoh_port + i, n)
        for i, (name, n) in enumerate(
            zip(cloud_names(args.clouds), split(args.robots, args.clouds), strict=True)
        )
    ]
    iaas = [
        Part(
            f"{m.cloud}'s IaaS",
            m.cloud,
            [
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
                f"{args.speedup:g}",
                "--log-level",
                "warning",
                *[arg for other in members[:i] for arg in ("--peer", other.zenoh)],
            ],
            var / f"{m.cloud}-iaas.log",
            env={"ROBOCLOUD_API_KEYS": f"demo={key}"},
            health=f"{m.url}/healthz",
        )
        for i, m in enumerate(members)
    ]
    sims = [
        Part(
            f"{m.cloud}'s simulator",
            m.cloud,
            [
                "sim",
                "--cloud",
                m.cloud,
                "--robots",
                str(m.robots),
                "--connect",
                m.zenoh,
                "--speedup",
                f"{args.speedup:g}",
                "--seed",
                str(i),
            ],
            var / f"{m.cloud}-sim.log",
        )
        for i, m in enumerate(members)
    ]
    wildfire = Part(
        "the Wildfire Suppression Application",
        WILDFIRE,
        [
            "wildfire",
            # Every cloud's IaaS, in order of preference: the page keeps working
            # while any one of them answers.
            *[arg for m in members for arg in ("--iaas", m.url)],
            "--listen",
            f"127.0.0.1:{args.wildfire_port}",
        ],
        var / "wildfire.log",
        env={"ROBOCLOUD_WILDFIRE_API_KEY": key},
        health=f"http://127.0.0.1:{args.wildfire_port}/",
    )
    nxt = nxt_parts(members[0], args, var) if args.nxt else []
    return members, [*iaas, *sims, *nxt, wildfire]


def nxt_parts(member: Member, args: argparse.Namespace, var: Path) -> list[Part]:
    """The thesis's NXT robots (README "LEGO Mindstorms NXT"): three stand-in bricks, a gateway."""
    bricks = str(NXT_BRICKS)
    stand_ins = [
        Part(
            f"the stand-in NXT brick {robot}",
            member.cloud,
            [
                "nxt-brick",
                *("--bricks", bricks, "--robot", robot, "--speedup", f"{args.speedup:g}"),
                *[arg for obstacle in NXT_OBSTACLES for arg in ("--obstacle", obstacle)],
            ],
            var / f"{robot}.log",
        )
        for robot in NXT_ROBOTS
    ]
    gateway = Part(
        f"{member.cloud}'s NXT gateway",
        member.cloud,
        ["nxt", "--cloud", member.cloud, "--connect", member.zenoh, "--bricks", bricks],
        var / f"{member.cloud}-nxt.log",
    )
    return [*stand_ins, gateway]


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    var = Path(args.var)
    var.mkdir(parents=True, exist_ok=True)
    key = os.environ.get("ROBOCLOUD_DEMO_KEY") or secrets.token_urlsafe(18)
    members, parts = plan(args, key)
    stopping = threading.Event()
    restart_all = threading.Event()
    asked: queue.SimpleQueue[str] = queue.SimpleQueue()  # lines typed in the terminal

    signal.signal(signal.SIGINT, lambda *_: stopping.set())
    signal.signal(signal.SIGTERM, lambda *_: stopping.set())
    signal.signal(signal.SIGUSR1, lambda *_: restart_all.set())
    interactive = sys.stdin is not None and sys.stdin.isatty()
    if interactive:
        threading.Thread(target=_read_lines, args=(sys.stdin, asked), daemon=True).start()
    try:
        # Every IaaS answers before the robots and the page start.
        iaas = [p for p in parts if p.argv[0] == "iaas"]
        for part in iaas:
            part.start()
        for part in iaas:
            _wait_healthy(part, stopping)
        for part in parts:
            if part.process is None:
                part.start()
        _wait_for_robots(members, stopping)
        if not stopping.is_set():
            print(_banner(members, parts, key, args, interactive), flush=True)
        while not stopping.is_set():
            for part in parts:
                if part.stopped() and not part.reported:
                    _report(part, interactive)
            wanted = _wanted(asked, restart_all, parts)
            if wanted is not None:
                _restart(parts, wanted, stopping)
            stopping.wait(0.25)
        print("stopping...", file=sys.stderr, flush=True)
        return 0
    except NotStarted as failed:
        print(f"{failed} Stopping.", file=sys.stderr, flush=True)
        return 1
    finally:
        _stop_all(parts)


def _read_lines(stream: IO[str], into: queue.SimpleQueue[str]) -> None:
    for line in stream:
        into.put(line.strip())


def _wanted(
    asked: queue.SimpleQueue[str], restart_all: threading.Event, parts: list[Part]
) -> set[str] | None:
    """The groups to restart now (empty: all that stopped), or None."""
    if restart_all.is_set():
        restart_all.clear()
        return set()
    try:
        line = asked.get_nowait()
    except queue.Empty:
        return None
    groups = {p.group for p in parts}
    if not line:
        return set()
    name = line if line in groups else f"cloud-{line}"
    if name not in groups:
        print(
            f"{line!r} is not a cloud here; type one of {', '.join(sorted(groups))}, "
            "or just Enter for everything that stopped.",
            file=sys.stderr,
            flush=True,
        )
        return None
    return {name}


def _report(part: Part, interactive: bool) -> None:
    part.reported = True
    code = part.process.returncode if part.process is not None else None
    others = (
        "the other clouds go on"
        if part.group != WILDFIRE
        else "the clouds go on (their APIs still answer)"
    )
    lines = [
        f"{part.title} stopped (exit {code}); {others}. Its log: {part.log}.",
        "  To restart what stopped: "
        + (f"press Enter here (or type {part.group} and Enter), or " if interactive else "")
        + f"kill -USR1 {os.getpid()}.",
        "  Or start it by hand (then Ctrl-C here does not stop it):",
        f"    {part.by_hand()}",
    ]
    print("\n".join(lines), file=sys.stderr, flush=True)


def _restart(parts: list[Part], groups: set[str], stopping: threading.Event) -> None:
    chosen = [p for p in parts if p.stopped() and (not groups or p.group in groups)]
    if not chosen:
        print("nothing has stopped; nothing to restart.", file=sys.stderr, flush=True)
        return
    for part in chosen:  # IaaSs first: the order of `parts`
        part.start()
        print(f"restarting {part.title} (pid {part.pid})...", file=sys.stderr, flush=True)
        if part.health is not None:
            try:
                _wait_healthy(part, stopping)
            except NotStarted as failed:
                print(failed, file=sys.stderr, flush=True)
                continue
            print(f"{part.title} is back.", file=sys.stderr, flush=True)


def _wait_healthy(part: Part, stopping: threading.Event) -> None:
    assert part.health is not None
    deadline = time.monotonic() + HEALTH_TIMEOUT_S
    while time.monotonic() < deadline and not stopping.is_set():
        if part.stopped():
            part.reported = True
            raise NotStarted(
                f"{part.title} did not start; its log {part.log} says why "
                "(is its port in use? another `make run`?)."
            )
        try:
            if httpx.get(part.health, timeout=1).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    if not stopping.is_set():
        raise NotStarted(f"{part.title} did not answer on {part.health} within 30 s.")


def _wait_for_robots(members: list[Member], stopping: threading.Event) -> None:
    """Until each IaaS sees its simulated robots, so the banner's first curl shows them.

    No error past the deadline: the banner comes anyway, and a simulator that
    stopped is reported by the main loop.
    """
    deadline = time.monotonic() + HEALTH_TIMEOUT_S
    waiting = list(members)
    while waiting and time.monotonic() < deadline and not stopping.is_set():
        member = waiting[0]
        try:
            if httpx.get(f"{member.url}/healthz", timeout=1).json()["robots"] >= member.robots:
                waiting.pop(0)
                continue
        except (httpx.TransportError, ValueError, KeyError):
            pass
        time.sleep(0.2)


def _stop_all(parts: list[Part]) -> None:
    running = [p.process for p in parts if p.process is not None and p.process.poll() is None]
    for process in reversed(running):
        process.terminate()
    deadline = time.monotonic() + 10
    for process in running:
        try:
            process.wait(max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
    for part in parts:
        if part.sink is not None:
            part.sink.close()


def _banner(
    members: list[Member],
    parts: list[Part],
    key: str,
    args: argparse.Namespace,
    interactive: bool,
) -> str:
    iaas_pid = {p.group: p.pid for p in parts if p.argv[0] == "iaas"}
    first, last = members[0], members[-1]
    auth = f"-H 'Authorization: Bearer {key}'"
    lines = [
        "",
        f"robocloud is running (demo pid {os.getpid()}):",
        f"  Wildfire Suppression Application: http://127.0.0.1:{args.wildfire_port}/",
    ]
    for m in members:
        lines.append(
            f"  {m.cloud}: {m.robots} simulated robots, API {m.url}/v1 "
            f"(docs {m.url}/docs), Zenoh {m.zenoh}, IaaS pid {iaas_pid[m.cloud]}"
        )
    var = Path(args.var)
    reset = "make reset" if var.resolve() == Path("var").resolve() else f"rm -rf {var}"
    lines += [
        f"  API key: {key}   (application 'demo'; send it as 'Authorization: Bearer {key}')",
        f"  Robots run {args.speedup:g}x faster than the clock.",
        f"  State: stores and logs in {var}/, kept between runs (earlier requests are there,",
        f"  unfinished ones resume). To start afresh: Ctrl-C, `{reset}`, then start again.",
        "",
        "Try (the robots of every cloud; without scope=federation, of this cloud only):",
        f"  curl -s {auth} '{first.url}/v1/robots?scope=federation' | head -c 300",
        "The live clouds, and a request:",
        f"  curl -s {auth} {first.url}/v1/clouds",
        f"  curl -s {auth} -H 'Content-Type: application/json' \\",
        '    -d \'{"location": [1000, 1000], "sensing": {"sound": 1}, '
        '"actuating": {"grabber": 1}, "max_robots": 5, "max_cost": 500, '
        '"max_time": 900, "min_battery": 50, "priority": "time"}\' \\',
        f"    {first.url}/v1/requests",
    ]
    if len(members) > 1:
        lines += [
            "",
            f"A cloud failing: kill {iaas_pid[last.cloud]} stops {last.cloud}'s IaaS; the others "
            "go on and re-plan its part.",
            "  Restart it: "
            + ("press Enter here, or " if interactive else "")
            + f"kill -USR1 {os.getpid()}.",
        ]
    if args.nxt:
        lines += [
            "",
            f"The thesis's NXT robots (stand-in bricks) are robots of {first.cloud}; a request "
            "they serve:",
            f"  curl -s {auth} -H 'Content-Type: application/json' \\",
            '    -d \'{"location": [10, 10], "sensing": {"light": 1}, "actuating": {"grabber": 1}, '
            '"max_robots": 3, "max_cost": 500, "max_time": 900, "priority": "time"}\' \\',
            f"    {first.url}/v1/requests",
        ]
    lines += ["", "Ctrl-C stops everything."]
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
