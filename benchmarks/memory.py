"""IaaS memory per robot: 10,000 and 100,000 ordinary robots on one IaaS (issue 25).

Real processes on loopback, as ``make run`` starts them: one ``robocloud iaas``
and one ``robocloud sim --gateway sim`` (its robots' states in batches). For
each size, a fresh IaaS: its resident memory (``VmRSS`` of ``/proc/<pid>/status``)
once it answers, before any robot; then once every robot is heard from and
``SETTLE`` seconds more (each robot has reported a few times); then after one
full listing of ``GET /v1/robots`` (the pages an application reads). Memory
per robot is the growth over the robots.

Run alone: ``python -m benchmarks.memory --sizes 10000,100000``.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import httpx

from benchmarks.one_cloud import one_cloud
from benchmarks.report import Column, Goal, SectionReport, Table, render_text

SIZES = (10_000, 100_000)
QUICK_SIZES = (10_000,)
SETTLE = 5.0  # seconds after the join: every robot has reported a few times
GOAL_ROBOTS, GOAL_BYTES = 100_000, 1_000_000_000  # 1 GB, not GiB


def rss_bytes(pid: int) -> int:
    """The resident memory of a process now."""
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError(f"no VmRSS for process {pid}")


def _list_all(client: httpx.Client, key: str) -> int:
    """Read every page of ``GET /v1/robots`` (following ``Link: rel=next``); how many listed."""
    listed, path = 0, "/v1/robots?limit=1000"
    while path:
        answer = client.get(path, headers={"Authorization": f"Bearer {key}"}, timeout=60)
        answer.raise_for_status()
        listed += len(answer.json())
        path = answer.links.get("next", {}).get("url", "")
    return listed


def one_size(n: int, workdir: Path) -> dict[str, Any]:
    row: dict[str, Any] = {"robots": n}
    with one_cloud(workdir, f"memory-{n}", start_within=60) as cloud:
        iaas = cloud.iaas
        time.sleep(1.0)
        row["rss_empty_mb"] = rss_bytes(iaas.pid) / 1e6
        seen = row["joined"] = cloud.start_sim(n, "--gateway", "sim").seen
        time.sleep(SETTLE)
        rss = rss_bytes(iaas.pid)
        row["rss_mb"] = rss / 1e6
        row["per_robot_kb"] = (rss - row["rss_empty_mb"] * 1e6) / max(seen, 1) / 1e3
        row["listed"] = _list_all(cloud.client, cloud.key)
        row["rss_listed_mb"] = rss_bytes(iaas.pid) / 1e6
    return row


def measure(sizes: Sequence[int], workdir: Path) -> SectionReport:
    workdir.mkdir(parents=True, exist_ok=True)
    rows = []
    for n in sizes:
        print(f"[memory] {n} robots ...", file=sys.stderr, flush=True)
        rows.append(one_size(n, workdir))
        print(f"  {rows[-1]}", file=sys.stderr, flush=True)
    table = Table(
        title="IaaS resident memory with ordinary robots (one gateway, 1 Hz)",
        columns=[
            Column("robots", "robots"),
            Column("joined", "heard from"),
            Column("rss_empty_mb", "RSS before robots MB", "{:.0f}"),
            Column("rss_mb", "RSS with robots MB", "{:.0f}"),
            Column("per_robot_kb", "per robot KB", "{:.2f}"),
            Column("rss_listed_mb", "RSS after a full GET /v1/robots MB", "{:.0f}"),
        ],
        rows=rows,
    )
    goals = []
    biggest = next((r for r in rows if r["robots"] == GOAL_ROBOTS), None)
    if biggest is not None:
        worst = max(biggest["rss_mb"], biggest["rss_listed_mb"]) * 1e6
        goals.append(Goal(
            "100,000 ordinary robots under 1 GB of IaaS memory",
            f"{worst / 1e6:.0f} MB ({biggest['joined']} heard from)",
            worst < GOAL_BYTES if biggest["joined"] >= GOAL_ROBOTS else None,
            f"{(GOAL_BYTES - worst) / 1e6:+.0f} MB",
        ))  # fmt: skip
    notes = [
        "Ordinary robots: the simulator's (a handful of capabilities, states of about "
        "500 bytes). A state is at most 64 KiB and a name 128 characters; a link follows "
        "at most 100,000 robots (Settings.max_fleet), so the worst case is bounded, not measured.",
        f"RSS with robots: {SETTLE:g} s after every robot was heard from.",
    ]
    return SectionReport(name="memory", title="IaaS memory per robot", rows=rows,
                         tables=[table], notes=notes, goals=goals)  # fmt: skip


def run(quick: bool, out: Path) -> SectionReport:
    return measure(QUICK_SIZES if quick else SIZES, out / "memory-run")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.memory",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--sizes", default=",".join(map(str, SIZES)))
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/memory-run"))
    args = parser.parse_args(argv)
    report = measure([int(s) for s in args.sizes.split(",")], args.out)
    print(render_text(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
