"""ROS 2 robots through one gateway: 200 stand-in Nav2 robots, each its own Zenoh router.

Real processes on loopback: the stand-in robots (``robocloud.gateways.ros2.standin``,
``STANDIN_PROCESSES`` processes of ``robots / STANDIN_PROCESSES`` robots, each
robot a Zenoh router on its own port, as on a robot) and one ``robocloud ros2``
gateway, which opens a session to each. This process is the cloud's router: it
reads the gateway's batches and sends each robot an assign to a goal too far to
reach in the run, so every robot drives, with Nav2's feedback at 20 Hz and
``/tf`` at 30 Hz, for the whole run.

- join: seconds from the gateway's process start (imports included) until
  every robot has been seen idle in a batch;
- CPU: the gateway's user + system time over the run after the assigns, as a
  share of one core; memory: its RSS every ``SAMPLE_EVERY`` seconds, the slope
  over the second half of the run saying whether it grows;
- what reached the gateway: the stand-ins' own counts of what they published
  (on two cores they may fall short of the rates asked), and the states the
  cloud received per robot per second (at most 1 Hz is the rule).

Run alone: ``python -m benchmarks.ros2 [--robots 200] [--seconds 600]``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import zenoh

from benchmarks.fleet import cpu_seconds
from benchmarks.report import Column, Goal, SectionReport, Table, render_text
from benchmarks.soak import rss_mb

ROBOTS, SECONDS = 200, 600.0
QUICK_ROBOTS, QUICK_SECONDS = 40, 20.0
STANDIN_PROCESSES = 4
FEEDBACK_HZ, TF_HZ = 20.0, 30.0
SAMPLE_EVERY = 5.0
JOIN_WITHIN = 60.0
CLOUD = "cloud-a"


def free_range(count: int) -> int:
    """A first port such that it and the next ``count - 1`` are free on loopback."""
    for base in range(20_000, 32_000 - count, 97):
        ok = True
        for port in range(base, base + count):
            with socket.socket() as sock:
                try:
                    sock.bind(("127.0.0.1", port))
                except OSError:
                    ok = False
                    break
        if ok:
            return base
    raise RuntimeError(f"no {count} free ports in a row")


def measure(robots: int, seconds: float, workdir: Path) -> SectionReport:
    workdir.mkdir(parents=True, exist_ok=True)
    base = free_range(robots + 1)
    cloud_endpoint = f"tcp/127.0.0.1:{base + robots}"
    per = -(-robots // STANDIN_PROCESSES)
    entries: dict[str, Any] = {}
    standins: list[subprocess.Popen[bytes]] = []
    for p in range(STANDIN_PROCESSES):
        first, count = p * per, min(per, robots - p * per)
        if count <= 0:
            break
        standins.append(subprocess.Popen(
            [sys.executable, "-m", "robocloud.gateways.ros2.standin", "--listen",
             f"tcp/127.0.0.1:{base + first}", "--count", str(count), "--namespace", f"/p{p}",
             "--speed", "0.05", "--feedback-hz", str(FEEDBACK_HZ), "--tf-hz", str(TF_HZ)],
            stdout=subprocess.DEVNULL, stderr=open(workdir / f"standin-{p}.err", "wb"),  # noqa: SIM115
        ))  # fmt: skip
        for i in range(count):
            entries[f"ros-{first + i:04d}"] = {
                "endpoint": f"tcp/127.0.0.1:{base + first + i}", "scheme": "rmw_zenoh",
                "distro": "jazzy", "namespace": f"/p{p}_{i}", "speed": 0.05,
                "offset": {"x": 10.0 * p, "y": 0.0, "yaw": 0.0},
                "capabilities": {"cam": {"kind": "sensing", "time": 1.0, "cost": 1.0}},
            }  # fmt: skip
    robots_file = workdir / "robots.json"
    robots_file.write_text(json.dumps({"robots": entries}))
    config = zenoh.Config()
    config.insert_json5("mode", '"router"')
    config.insert_json5("listen/endpoints", json.dumps([cloud_endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(config)
    lock = threading.Lock()
    idle: set[str] = set()
    states = [0]

    def on_batch(sample: zenoh.Sample) -> None:
        batch = json.loads(sample.payload.to_bytes())
        with lock:
            states[0] += len(batch)
            idle.update(s["id"] for s in batch if s["status"] == "idle")

    subscriber = session.declare_subscriber(f"robocloud/{CLOUD}/fleets/*/states", on_batch)
    time.sleep(2.0)  # the stand-ins' routers up (their imports take about a second)
    started = time.monotonic()
    gateway = subprocess.Popen(
        [sys.executable, "-m", "robocloud.cli.main", "ros2", "--cloud", CLOUD, "--connect",
         cloud_endpoint, "--robots", str(robots_file), "--log-level", "warning"],
        stdout=subprocess.DEVNULL, stderr=open(workdir / "gateway.log", "wb"),  # noqa: SIM115
    )  # fmt: skip
    row: dict[str, Any] = {"robots": robots, "seconds": seconds}
    try:
        join = None
        while time.monotonic() - started < JOIN_WITHIN:
            with lock:
                if len(idle) >= robots:
                    join = time.monotonic() - started
                    break
            time.sleep(0.1)
        row["join_s"] = join
        with lock:
            row["joined"] = len(idle)
        for robot in entries:  # a goal 1 km away: driving at 5 cm/s for the whole run
            assign = {"type": "assign", "request_id": f"bench-{robot}", "location": [1000.0, 0.0],
                      "capabilities": ["cam"]}  # fmt: skip
            session.get(f"robocloud/{CLOUD}/robots/{robot}/cmd", payload=json.dumps(assign),
                        timeout=2.0)  # fmt: skip
        time.sleep(2.0)
        with lock:
            states_before = states[0]
        cpu_before, t0 = cpu_seconds(gateway.pid), time.monotonic()
        memory: list[tuple[float, float]] = []
        while (elapsed := time.monotonic() - t0) < seconds:
            memory.append((elapsed, rss_mb(gateway.pid)))
            time.sleep(min(SAMPLE_EVERY, max(0.0, seconds - elapsed)))
        took = time.monotonic() - t0
        row["gateway_cpu"] = 100.0 * (cpu_seconds(gateway.pid) - cpu_before) / took
        with lock:
            row["state_hz"] = (states[0] - states_before) / took / robots
        memory.append((took, rss_mb(gateway.pid)))
        row["rss_start"], row["rss_end"] = memory[0][1], memory[-1][1]
        row["rss_max"] = max(m for _, m in memory)
        half = [(t, m) for t, m in memory if t >= took / 2]
        row["rss_slope"] = _slope(half) * 60.0 if len(half) >= 2 else None  # MB per minute
        (workdir / "memory.csv").write_text(
            "seconds,rss_mb\n" + "".join(f"{t:.1f},{m:.1f}\n" for t, m in memory)
        )
    finally:
        gateway.terminate()
        gateway.wait(20)
        for p in standins:
            p.terminate()
        for p in standins:
            p.wait(30)
        subscriber.undeclare()  # type: ignore[no-untyped-call]
        session.close()  # type: ignore[no-untyped-call]
    tf = feedback = 0.0
    for path in workdir.glob("standin-*.err"):
        found = re.search(r"tf (\d+)/s, feedback (\d+)/s", path.read_text())
        if found:
            tf += float(found[1])
            feedback += float(found[2])
    row["tf_hz"], row["feedback_hz"] = tf / robots, feedback / robots
    return report(row)


def _slope(points: Sequence[tuple[float, float]]) -> float:
    n = len(points)
    mx = sum(t for t, _ in points) / n
    my = sum(m for _, m in points) / n
    var = sum((t - mx) ** 2 for t, _ in points)
    return sum((t - mx) * (m - my) for t, m in points) / var if var else 0.0


def report(row: dict[str, Any]) -> SectionReport:
    table = Table(
        title="Stand-in Nav2 robots through one ROS 2 gateway, each robot its own Zenoh router",
        columns=[
            Column("robots", "robots"),
            Column("join_s", "all idle after s", "{:.1f}"),
            Column("tf_hz", "tf Hz per robot (sent)", "{:.1f}"),
            Column("feedback_hz", "feedback Hz per robot (sent)", "{:.1f}"),
            Column("state_hz", "states Hz per robot (to the cloud)", "{:.2f}"),
            Column("gateway_cpu", "gateway CPU % of a core", "{:.0f}"),
            Column("rss_start", "RSS MB at start", "{:.0f}"),
            Column("rss_end", "at end", "{:.0f}"),
            Column("rss_slope", "MB/min (2nd half)", "{:+.2f}"),
            Column("seconds", "run s", "{:.0f}"),
        ],
        rows=[row],
    )
    goals = [
        Goal(
            f"{row['robots']} robots idle within 15 s of the gateway's start (our bound)",
            f"{row['join_s']:.1f} s" if row["join_s"] is not None else f"{row['joined']} joined",
            row["join_s"] is not None and row["join_s"] < 15.0,
            f"{15.0 - row['join_s']:+.1f} s" if row["join_s"] is not None else "n/a",
        ),
        Goal(
            "the cloud sees at most 1 state a second per robot while feedback runs",
            f"{row['state_hz']:.2f} Hz",
            row["state_hz"] <= 1.05,
            f"{1.0 - row['state_hz']:+.2f} Hz",
        ),
    ]
    if row.get("rss_slope") is not None and row["seconds"] >= 300:
        goals.append(Goal(
            "memory flat: RSS grows under 1 MB a minute over the run's second half",
            f"{row['rss_slope']:+.2f} MB/min",
            row["rss_slope"] < 1.0,
            f"{1.0 - row['rss_slope']:+.2f} MB/min",
        ))  # fmt: skip
    notes = [
        f"Real processes on loopback on the same 2 cores: {STANDIN_PROCESSES} stand-in "
        "processes (pycdr2), the gateway, and this process as the cloud's router.",
        f"Asked of each robot: /tf at {TF_HZ:g} Hz, feedback at {FEEDBACK_HZ:g} Hz (every robot "
        "drives a goal for the whole run); the stand-ins' own counts say what they sent.",
        "The gateway reads at most 10 /tf and 5 feedback samples a second per robot.",
    ]
    return SectionReport(name="ros2", title="ROS 2 gateway", rows=[row], tables=[table],
                         notes=notes, goals=goals)  # fmt: skip


def run(quick: bool, out: Path) -> SectionReport:
    robots, seconds = (QUICK_ROBOTS, QUICK_SECONDS) if quick else (ROBOTS, SECONDS)
    return measure(robots, seconds, out / "ros2-run")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.ros2",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--robots", type=int, default=ROBOTS)
    parser.add_argument("--seconds", type=float, default=SECONDS)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = parser.parse_args(argv)
    if not (1 <= args.robots <= 1000 and 5 <= args.seconds <= 7200):
        print("error: --robots 1 to 1000 and --seconds 5 to 7200.", file=sys.stderr)
        return 2
    print(render_text(measure(args.robots, args.seconds, args.out / "ros2-run")), flush=True)
    return 0


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    raise SystemExit(main())
