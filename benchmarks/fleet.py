"""Fleet size: 5,000, 20,000 and 50,000 simulated robots on one IaaS.

Real processes on loopback, as ``make run`` starts them: one ``robocloud iaas``
and one ``robocloud sim`` (a fleet gateway, ``--gateway sim``, publishing its
robots' states in batches; ``--per-robot`` for a key per robot, as before
gateways). For each size, a fresh IaaS and simulator:

- join: seconds from starting the simulator until the IaaS counts every
  robot (``/healthz``'s ``robots``, polled every 0.25 s; the process start of
  the simulator, about a second of Python imports, is included). Given up
  after ``GIVE_UP`` seconds, saying how many had joined.
- CPU: the share of one core used by the IaaS and by the simulator (user +
  system time from ``/proc/<pid>/stat``) over ``CPU_WINDOW`` seconds, a few
  seconds after the join, while every robot reports once a second.
- POST-to-dispatched: ``DISPATCHES`` sequential requests (a grabber and a
  sound sensor near the middle of the forest), each canceled once dispatched;
  the client's time from sending the POST to the event saying dispatched.
  No new request after ``DISPATCH_FOR`` seconds.

Run alone: ``python -m benchmarks.fleet --sizes 5000,20000`` (``--per-robot``
for the old way, ``--src DIR`` to run the processes from another checkout,
e.g. main's ``src``, for a before/after comparison).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from benchmarks.one_cloud import GIVE_UP, one_cloud
from benchmarks.report import Column, Goal, SectionReport, Table, render_text
from benchmarks.service import post_to_dispatched

SIZES = (5_000, 20_000, 50_000)
QUICK_SIZES = (5_000,)
SETTLE = 3.0  # seconds between the join and the CPU window
CPU_WINDOW = 10.0
DISPATCHES = 30
DISPATCH_FOR = 90.0  # seconds at most for the requests of one size
_TICK = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a process so far (all its threads)."""
    with open(f"/proc/{pid}/stat") as stat:
        fields = stat.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / _TICK


def one_size(
    n: int, workdir: Path, *, gateway: bool, src: Path | None, dispatches: int
) -> dict[str, Any]:
    row: dict[str, Any] = {"robots": n, "mode": "gateway" if gateway else "per-robot"}
    with one_cloud(workdir, f"fleet-{n}", start_within=30, src=src) as cloud:
        joined = cloud.start_sim(n, *(["--gateway", "sim"] if gateway else []))
        iaas, sim, seen = cloud.iaas, joined.sim, joined.seen
        row["joined"] = seen
        row["join_s"] = joined.seconds if seen >= n else None
        if seen < n:
            print(f"  {n}: only {seen} robots after {joined.seconds:.0f} s; measuring anyway",
                  file=sys.stderr, flush=True)  # fmt: skip
        time.sleep(SETTLE)
        before = {p.pid: cpu_seconds(p.pid) for p in (iaas, sim)}
        t0 = time.monotonic()
        time.sleep(CPU_WINDOW)
        spent = time.monotonic() - t0
        row["iaas_cpu"] = 100 * (cpu_seconds(iaas.pid) - before[iaas.pid]) / spent
        row["sim_cpu"] = 100 * (cpu_seconds(sim.pid) - before[sim.pid]) / spent
        row["heard"] = cloud.robots()
        if seen > 0 and dispatches > 0:
            try:
                got = post_to_dispatched(
                    cloud.url, cloud.key, dispatches, DISPATCH_FOR, label="fleet bench"
                )
            except (httpx.HTTPError, AssertionError, KeyError) as error:
                print(f"  {n}: the dispatches failed: {error}", file=sys.stderr, flush=True)
                got = {"client": [], "server": [], "sent": dispatches}
            row["dispatched"] = len(got["client"])
            row["sent"] = got["sent"]
            row["p50"] = statistics.median(got["client"]) if got["client"] else None
            row["p99"] = float(np.percentile(got["client"], 99)) if got["client"] else None
            row["server_p50"] = statistics.median(got["server"]) if got["server"] else None
    return row


def measure(
    sizes: Sequence[int],
    workdir: Path,
    *,
    gateway: bool = True,
    src: Path | None = None,
    dispatches: int = DISPATCHES,
) -> SectionReport:
    workdir.mkdir(parents=True, exist_ok=True)
    rows = []
    for n in sizes:
        print(f"[fleet] {n} robots ...", file=sys.stderr, flush=True)
        rows.append(one_size(n, workdir, gateway=gateway, src=src, dispatches=dispatches))
        print(f"  {rows[-1]}", file=sys.stderr, flush=True)
    mode = "one gateway (batches)" if gateway else "a key per robot"
    table = Table(
        title=f"Robots on one IaaS, one simulator ({mode}), reporting at 1 Hz",
        columns=[
            Column("robots", "robots"),
            Column("join_s", "all selectable after s", "{:.1f}"),
            Column("joined", "joined"),
            Column("iaas_cpu", "IaaS CPU % of a core", "{:.0f}"),
            Column("sim_cpu", "simulator CPU %", "{:.0f}"),
            Column("p50", "POST-to-dispatched p50 ms", "{:.0f}"),
            Column("p99", "p99 ms", "{:.0f}"),
            Column("dispatched", "dispatched"),
        ],
        rows=rows,
    )
    goals = []
    biggest = next((r for r in rows if r["robots"] == 50_000), None)
    if biggest is not None:
        join = biggest["join_s"]
        goals.append(
            Goal(
                "50,000 robots selectable within 15 s of the simulator's start",
                f"{join:.1f} s"
                if join is not None
                else f"{biggest['joined']} after {GIVE_UP:.0f} s",
                join is not None and join < 15.0,
                f"{15.0 - join:+.1f} s" if join is not None else "n/a",
            )
        )
        goals.append(
            Goal(
                "IaaS under 50% of a core at 1 Hz (50,000 robots)",
                f"{biggest['iaas_cpu']:.0f}%"
                + ("" if join is not None else f" with only {biggest['joined']} robots"),
                # Not judged when the fleet did not join: fewer robots cost less.
                biggest["iaas_cpu"] < 50.0 if join is not None else None,
                f"{50.0 - biggest['iaas_cpu']:+.0f} points",
            )
        )
        p50 = biggest.get("p50")
        goals.append(Goal(
            "POST-to-dispatched median under 50 ms (50,000 robots)",
            f"{p50:.0f} ms" if p50 is not None else "none dispatched",
            p50 is not None and p50 < 50.0,
            f"{50.0 - p50:+.0f} ms" if p50 is not None else "n/a",
        ))  # fmt: skip
    notes = [
        "Real processes on loopback on the same 2 cores: the IaaS, the simulator and this "
        "client. Robots at the clock's speed, without churn; each request is canceled once "
        "dispatched, so its robots are free again.",
        f"Join: from the simulator's process start (imports included) until /healthz counts "
        f"every robot; CPU over {CPU_WINDOW:g} s, {SETTLE:g} s after the join.",
    ]
    return SectionReport(name="fleet", title="Fleet size on one IaaS", rows=rows,
                         tables=[table], notes=notes, goals=goals)  # fmt: skip


def run(quick: bool, out: Path) -> SectionReport:
    return measure(QUICK_SIZES if quick else SIZES, out / "fleet-run")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.fleet",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--sizes",
        default=",".join(map(str, SIZES)),
        help="robot counts, comma-separated (default 5000,20000,50000)",
    )
    parser.add_argument(
        "--per-robot",
        action="store_true",
        help="the simulator publishes on a key per robot (no gateway)",
    )
    parser.add_argument("--src", type=Path, help="run the processes from this source tree")
    parser.add_argument("--dispatches", type=int, default=DISPATCHES)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = parser.parse_args(argv)
    try:
        sizes = [int(s) for s in args.sizes.split(",") if s.strip()]
    except ValueError:
        print(f"error: --sizes must be whole numbers, not {args.sizes!r}.", file=sys.stderr)
        return 2
    report = measure(sizes, args.out / "fleet-run", gateway=not args.per_robot, src=args.src,
                     dispatches=args.dispatches)  # fmt: skip
    print(render_text(report), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
