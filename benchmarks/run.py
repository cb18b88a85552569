"""Entry point: ``python -m benchmarks.run [--quick] [--only SECTION]`` (``make bench``).

Runs each section, prints its tables to stdout and writes
``benchmarks/results/<section>.csv`` and ``<section>.md`` (the tables, the
goals and the machine they were measured on), plus the section's figures.
Add a section by appending to ``SECTIONS``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks import (
    federation,
    fleet,
    memory,
    missions,
    nxt,
    ros2,
    router_trace,
    select_command,
    selection,
    service,
    soak,
    throughput,
)
from benchmarks.machine import reference_ms, steal_ticks, stolen
from benchmarks.report import SectionReport, render_markdown, render_text, write_csv

RESULTS = Path(__file__).resolve().parent / "results"


@dataclass(frozen=True)
class Section:
    name: str
    run: Callable[[bool, Path], SectionReport]  # (quick, out_dir) -> report


SECTIONS: list[Section] = [
    Section("selection", selection.run),
    Section("select-command", select_command.run),
    Section("service", service.run),
    Section("soak", soak.run),
    Section("federation", federation.run),
    Section("throughput", throughput.run),
    Section("fleet", fleet.run),
    Section("nxt", nxt.run),
    Section("ros2", ros2.run),
    Section("missions", missions.run),
    Section("memory", memory.run),
    Section("router-trace", router_trace.run),
]


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as info:
            for line in info:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def load_average() -> str:
    try:
        one, five, fifteen = os.getloadavg()
    except OSError:
        return "n/a"
    return f"{one:.2f} {five:.2f} {fifteen:.2f}"


def git_state() -> str:
    import subprocess

    root = Path(__file__).resolve().parent.parent
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, check=True,
                              capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=root, check=True, capture_output=True, text=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return "n/a"
    return f"{head}{' with uncommitted changes' if dirty.strip() else ''}"


@dataclass(frozen=True)
class Before:
    """What is read of the machine before a section runs, to compare with after."""

    started: dt.datetime
    load: str
    reference_ms: float
    ticks: tuple[int, int] | None

    @classmethod
    def now(cls) -> Before:
        return cls(dt.datetime.now(dt.UTC).astimezone(), load_average(), reference_ms(),
                   steal_ticks())


def machine(before: Before, quick: bool) -> list[tuple[str, str]]:
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count() or 0
    versions = [("Python", platform.python_version()), ("numpy", np.__version__)]
    try:
        import pymoo

        versions.append(("pymoo", pymoo.__version__))
    except ImportError:
        pass
    return [
        ("CPU", cpu_model()),
        ("cores", f"{os.cpu_count()} logical, {usable} usable by this process"),
        ("OS", platform.platform()),
        *versions,
        ("commit", git_state()),
        ("date", before.started.isoformat(timespec="seconds")),
        ("load average (1, 5, 15 min) before", before.load),
        ("load average (1, 5, 15 min) after", load_average()),
        ("reference workload ms (median of 7), before and after",
         f"{before.reference_ms:.1f} and {reference_ms():.1f}"),
        ("CPU time stolen by the host during the section", stolen(before.ticks)),
        ("mode", "--quick (smoke check, fewer sizes and repetitions)" if quick else "full"),
    ]


def main(argv: Sequence[str] | None = None) -> int:
    names = [s.name for s in SECTIONS]
    parser = argparse.ArgumentParser(prog="python -m benchmarks.run", description=__doc__)
    parser.add_argument("--quick", action="store_true",
                        help="smaller sizes and fewer repetitions, for a smoke check")
    parser.add_argument("--only", choices=names, action="append",
                        help="run only this section (repeatable)")
    parser.add_argument("--out", type=Path, default=RESULTS, help="where results go")
    args = parser.parse_args(argv)
    chosen = [s for s in SECTIONS if not args.only or s.name in args.only]
    args.out.mkdir(parents=True, exist_ok=True)
    for section in chosen:
        before = Before.now()
        print(f"[{section.name}] running (load average {before.load}, reference workload "
              f"{before.reference_ms:.1f} ms) ...", file=sys.stderr, flush=True)
        report = section.run(args.quick, args.out)
        text = render_text(report)
        print(text, flush=True)
        write_csv(args.out / f"{section.name}.csv", report.rows)
        info = machine(before, args.quick)
        (args.out / f"{section.name}.md").write_text(render_markdown(report, info))
        print("\n".join(f"{k}: {v}" for k, v in info), flush=True)
        print(f"wrote {args.out / (section.name + '.csv')}, {args.out / (section.name + '.md')}",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
