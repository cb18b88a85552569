"""The ``robocloud select`` command on large scenarios: wall time and peak memory of
the whole process, and where the time goes.

Each run is a real process, ``python -m robocloud.cli.main select FILE
--timings --budget 0``, from the interpreter's start to its exit (no time
budget: on a loaded machine the default 2 s could cut a search, and the
outputs compared below would differ). The wall time is measured around it
(``time.perf_counter``), the peak resident memory and the CPU time come from
``os.wait4`` (the kernel's ``ru_maxrss`` of that one child), the split
(reading, filtering, ranking, optimisation, writing) from the command's
``--timings`` line. Every figure is the median of the runs.

The scenarios are ``robocloud scenario wildfire --robots N`` (seed 0, 3
clouds: 10% of the robots are candidates), written to a temporary directory
by that command, also timed. Both readers are measured on the smaller size
in the same run: ``--reader objects`` (one pydantic ``Robot`` per robot, the
former reader) as the reference, and the columnar reader; their outputs must
be the same document but for ``elapsed_ms``. The largest size also gets one
run of the objects reader in a full run (about 45 s and 5 GB).
"""

from __future__ import annotations

import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from benchmarks.report import Column, Goal, Row, SectionReport, Table

LARGE = 1_000_000
REFERENCE = 100_000
QUICK_LARGE = 200_000
QUICK_REFERENCE = 20_000
RUNS = 5
QUICK_RUNS = 3
GOAL_WALL_S = 8.0
GOAL_RSS_BYTES = 2_000_000_000  # 2 GB
PYTHON = [sys.executable, "-m", "robocloud.cli.main"]
TIMINGS = re.compile(r"robocloud: timings \(ms\): (.*)")


@dataclass(frozen=True)
class Run:
    wall_s: float
    cpu_s: float
    peak_bytes: int
    split: dict[str, float]  # ms
    output: dict[str, Any]


def measured(argv: list[str], out: Path) -> tuple[float, float, int, str]:
    """(wall s, CPU s, peak RSS bytes, stderr) of one process; stdout goes to ``out``."""
    with out.open("wb") as stdout, tempfile.TemporaryFile() as stderr:
        started = time.perf_counter()
        process = subprocess.Popen(argv, stdout=stdout, stderr=stderr)
        _, status, usage = os.wait4(process.pid, 0)
        wall = time.perf_counter() - started
        process.returncode = os.waitstatus_to_exitcode(status)
        stderr.seek(0)
        errors = stderr.read().decode(errors="replace")
    if process.returncode != 0:
        raise RuntimeError(f"{' '.join(argv[3:])} exited {process.returncode}: {errors}")
    # ru_maxrss is in KiB on Linux.
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss * 1024, errors


def run_select(path: Path, reader: str, workdir: Path) -> Run:
    out = workdir / f"{path.stem}-{reader}.json"
    wall, cpu, peak, errors = measured(
        [*PYTHON, "select", str(path), "--timings", "--budget", "0", "--reader", reader], out
    )
    found = TIMINGS.search(errors)
    if found is None:
        raise RuntimeError(f"no timings from select: {errors}")
    split = {name: float(ms) for name, ms in
             (part.rsplit(" ", 1) for part in found.group(1).split(", "))}
    output = json.loads(out.read_bytes())
    out.unlink()
    output.pop("elapsed_ms")
    return Run(wall, cpu, peak, split, output)


def generate(robots: int, workdir: Path) -> tuple[Path, float, int]:
    path = workdir / f"wildfire-{robots}.json"
    wall, _, peak, _ = measured(
        [*PYTHON, "scenario", "wildfire", "--robots", str(robots), "--output", str(path)],
        workdir / "scenario.out",
    )
    return path, wall, peak


def load_average() -> str:
    try:
        return " ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "n/a"


def summary(robots: int, reader: str, runs: list[Run], file_bytes: int) -> Row:
    def median(values: list[float]) -> float:
        return statistics.median(values)

    row: Row = {
        "robots": robots,
        "reader": reader,
        "runs": len(runs),
        "file_mb": file_bytes / 1e6,
        "candidates": runs[0].output["candidates"],
        "wall_s": median([r.wall_s for r in runs]),
        "wall_min_s": min(r.wall_s for r in runs),
        "cpu_s": median([r.cpu_s for r in runs]),
        "peak_mb": median([r.peak_bytes / 1e6 for r in runs]),
        "load_average": load_average(),
    }
    for stage in ("reading", "filtering", "ranking", "optimisation", "writing", "total"):
        row[f"{stage}_ms"] = median([r.split.get(stage, float("nan")) for r in runs])
    return row


def measure(path: Path, robots: int, reader: str, repeats: int, workdir: Path) -> tuple[Row, Run]:
    runs = [run_select(path, reader, workdir) for _ in range(repeats)]
    for r in runs[1:]:
        if r.output != runs[0].output:  # never seen without a budget
            changed = sorted(k for k in r.output if r.output[k] != runs[0].output.get(k))
            print(f"  {reader} at {robots:,}: a run answered differently ({', '.join(changed)})",
                  file=sys.stderr, flush=True)
    print(f"  {robots:>9,} robots, {reader}: median {statistics.median(r.wall_s for r in runs):.2f}"
          " s", file=sys.stderr, flush=True)
    row = summary(robots, reader, runs, path.stat().st_size)
    row["complete_runs"] = sum(bool(r.output["complete"]) for r in runs)
    row["same_across_runs"] = all(r.output == runs[0].output for r in runs)
    return row, runs[0]


def run(quick: bool, out_dir: Path) -> SectionReport:
    large = QUICK_LARGE if quick else LARGE
    reference = QUICK_REFERENCE if quick else REFERENCE
    repeats = QUICK_RUNS if quick else RUNS
    rows: list[Row] = []
    made: list[Row] = []
    with tempfile.TemporaryDirectory(prefix="robocloud-select-") as tmp:
        workdir = Path(tmp)
        paths = {}
        for robots in (reference, large):
            path, wall, peak = generate(robots, workdir)
            paths[robots] = path
            made.append({"robots": robots, "wall_s": wall, "peak_mb": peak / 1e6,
                         "file_mb": path.stat().st_size / 1e6})
        old_row, old = measure(paths[reference], reference, "objects", repeats, workdir)
        new_row, new = measure(paths[reference], reference, "columnar", repeats, workdir)
        same_reference = old.output == new.output
        large_row, large_run = measure(paths[large], large, "columnar", repeats, workdir)
        rows += [old_row, new_row, large_row]
        same_large: bool | None = None
        if not quick:
            before_row, before = measure(paths[large], large, "objects", 1, workdir)
            rows.append(before_row)
            same_large = before.output == large_run.output
    for row in rows:
        row["same_output"] = (same_reference if row["robots"] == reference else same_large)
    ratio = old_row["wall_s"] / new_row["wall_s"]
    memory_ratio = old_row["peak_mb"] / new_row["peak_mb"]
    timing = Table(
        "The whole command, a real process: median wall, CPU and peak RSS, and the split "
        "(median ms, from --timings)",
        [
            Column("robots", "robots", "{:,}"),
            Column("reader", "reader"),
            Column("runs", "runs"),
            Column("file_mb", "file MB", "{:.0f}"),
            Column("candidates", "candidates", "{:,}"),
            Column("wall_s", "wall s", "{:.2f}"),
            Column("cpu_s", "CPU s", "{:.2f}"),
            Column("peak_mb", "peak RSS MB", "{:.0f}"),
            Column("reading_ms", "reading ms", "{:.0f}"),
            Column("filtering_ms", "filtering ms", "{:.0f}"),
            Column("ranking_ms", "ranking ms", "{:.0f}"),
            Column("optimisation_ms", "optimisation ms", "{:.0f}"),
            Column("writing_ms", "writing ms", "{:.0f}"),
            Column("complete_runs", "complete runs"),
            Column("same_across_runs", "runs agree", lambda v: "yes" if v else "NO"),
            Column("same_output", "same output", lambda v: "yes" if v else "NO"),
            Column("load_average", "load avg after"),
        ],
        rows,
        note=("wall: from the process's start to its exit, interpreter start-up and imports "
              "included (the split's total leaves them out). CPU: user + system time of the "
              "process. filtering includes computing each candidate's t_i and c_i; "
              "optimisation is everything after the ranking (cheap tests, pruning, the exact "
              "search, thresholds, choice). complete runs: runs whose search finished (no "
              "budget: all of them). same output: the document of the first run equals the "
              "other reader's at that size, elapsed_ms aside."),
    )
    generating = Table(
        "Writing the scenario (robocloud scenario wildfire --output, one run)",
        [
            Column("robots", "robots", "{:,}"),
            Column("file_mb", "file MB", "{:.0f}"),
            Column("wall_s", "wall s", "{:.2f}"),
            Column("peak_mb", "peak RSS MB", "{:.0f}"),
        ],
        made,
    )
    size = f"{large:,} robots"
    goals = [
        Goal(f"select on {size}: wall < {GOAL_WALL_S:g} s", f"{large_row['wall_s']:.2f} s "
             f"(median of {repeats})", large_row["wall_s"] < GOAL_WALL_S,
             f"{GOAL_WALL_S / large_row['wall_s']:.2f}x under" if large_row["wall_s"]
             < GOAL_WALL_S else f"{large_row['wall_s'] / GOAL_WALL_S:.2f}x over"),
        Goal(f"select on {size}: peak RSS < 2 GB", f"{large_row['peak_mb']:.0f} MB",
             large_row["peak_mb"] * 1e6 < GOAL_RSS_BYTES,
             f"{GOAL_RSS_BYTES / 1e6 / large_row['peak_mb']:.2f}x under"),
        Goal(f"same output as the objects reader ({reference:,} robots"
             f"{'' if quick else f' and {large:,}'})",
             f"{same_reference}{'' if same_large is None else f', {same_large}'}",
             same_reference and same_large is not False, ""),
    ]
    if quick:
        goals[0] = Goal(goals[0].goal, goals[0].measured + " (--quick: not the goal's size)",
                        None, goals[0].margin)
        goals[1] = Goal(goals[1].goal, goals[1].measured + " (--quick: not the goal's size)",
                        None, goals[1].margin)
    notes = [
        f"Reference in the same run, {reference:,} robots: the objects reader takes "
        f"{ratio:.1f}x the columnar reader's wall time and {memory_ratio:.1f}x its peak memory.",
        "Scenarios: robocloud scenario wildfire --robots N (seed 0, 3 clouds), in a temporary "
        "directory removed afterwards.",
    ]
    return SectionReport(
        name="select-command",
        title="robocloud select on large scenarios: the whole command",
        rows=rows + [{"scenario_" + k: v for k, v in row.items()} for row in made],
        tables=[timing, generating],
        notes=notes,
        goals=goals,
    )
