"""The mission planner: makespans and solve times against CP-SAT given long, and the greedy.

Two parts:

- **The 12 visible MRTA-Benchmark instances** (8 tasks, 3 robots; read from
  ``../shared/mrta`` beside the clone): the planner's makespan against the
  dataset's proven optimum, and each solve time (goal: the optimum, within
  2 s each).
- **Generated missions** with the dataset's distributions
  (``robocloud.planning.generate``) at 8/3, 15/5, 30/10 and 50/20 tasks/robots:
  ``solve`` as ``robocloud plan`` runs it (10 s: the exact model for the small
  ones, the anytime method, construction plus large-neighbourhood search, for
  the others) against the exact CP-SAT model given 120 s (warm-started from
  the same construction), and against the greedy baseline (the tasks one by
  one, each by today's single-task selection); with the lower bound each
  found (the best of the two is the gap's reference).

Times are each plan's own solve time inside the planner's child process
(``elapsed_s``); a warm-up plan first in each child takes the child's start
(the OR-Tools import) out of them. ``--quick``: one instance per size, 2 s
and 10 s instead of 10 s and 120 s.

The MRTA-Benchmark dataset is by Jakob Bichler (TU Delft, Autonomous
Multi-Robot Lab), DOI 10.4121/10e28ee0-9ad9-450d-8be7-6e6a91f2931f, CC BY 4.0;
results computed from it keep this credit.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

from benchmarks.report import Column, Goal, Row, SectionReport, Table
from robocloud.planning.generate import generate
from robocloud.planning.greedy import greedy
from robocloud.planning.mrta import read_instance
from robocloud.planning.plan import Method, Plan
from robocloud.planning.problem import Problem
from robocloud.planning.solve import solve_all

SIZES = [(8, 3), (15, 5), (30, 10), (50, 20)]
SEEDS = (1, 2)
QUICK_SEEDS = (1,)
ANYTIME_S, EXACT_S = 10.0, 120.0
QUICK_ANYTIME_S, QUICK_EXACT_S = 2.0, 10.0
VISIBLE_GOAL_S = 2.0
CREDIT = ("MRTA-Benchmark dataset by Jakob Bichler (TU Delft), DOI "
          "10.4121/10e28ee0-9ad9-450d-8be7-6e6a91f2931f, CC BY 4.0.")
# As in CI: shared/ beside the clone; ROBOCLOUD_MRTA_DIR elsewhere (a git worktree).
MRTA = Path(
    os.environ.get("ROBOCLOUD_MRTA_DIR")
    or Path(__file__).resolve().parents[1].parent / "shared" / "mrta"
) / "visible"


def _warm(problems: list[Problem], limit: float, method: Method | None) -> list[Plan]:
    """``solve_all`` with a small warm-up plan first, to keep the child's start out."""
    warm_up = read_instance(generate(3, 2, 0))
    return solve_all([warm_up, *problems], limit, 0, method)[1:]


def _visible(rows: list[Row]) -> list[Row]:
    if not (MRTA / "manifest.json").is_file():
        raise SystemExit(f"benchmarks/missions.py: the MRTA-Benchmark files are missing "
                         f"({MRTA / 'manifest.json'}); put shared/ beside the clone or set "
                         "ROBOCLOUD_MRTA_DIR.")
    manifest = json.loads((MRTA / "manifest.json").read_text())["instances"]
    problems = [read_instance(json.loads((MRTA / r["instance"]).read_text())) for r in manifest]
    plans = _warm(problems, 10.0, None)
    out = []
    for row, plan in zip(manifest, plans, strict=True):
        assert plan.schedule is not None
        out.append({
            "part": "visible", "instance": row["id"], "optimum": row["optimal_makespan"],
            "makespan": plan.schedule.makespan, "solve_s": plan.elapsed_s,
            "proven": plan.optimal,
            "difference": plan.schedule.makespan - row["optimal_makespan"],
        })
    rows.extend(out)
    return out


def _generated(rows: list[Row], quick: bool) -> list[Row]:
    seeds = QUICK_SEEDS if quick else SEEDS
    anytime_s, exact_s = (QUICK_ANYTIME_S, QUICK_EXACT_S) if quick else (ANYTIME_S, EXACT_S)
    cases = [(m, n, s) for m, n in SIZES for s in seeds]
    problems = [read_instance(generate(m, n, s)) for m, n, s in cases]
    greedy_rows = []
    for problem in problems:
        started = time.perf_counter()
        schedule = greedy(problem)
        assert schedule is not None
        greedy_rows.append((schedule.makespan, time.perf_counter() - started))
    planned = _warm(problems, anytime_s, None)
    exact = _warm(problems, exact_s, "exact")
    out = []
    for (m, n, seed), plan, best, (greedy_makespan, greedy_s) in zip(
        cases, planned, exact, greedy_rows, strict=True
    ):
        assert plan.schedule is not None and best.schedule is not None
        bound = max(plan.lower_bound or 0.0, best.lower_bound or 0.0)
        makespan = plan.schedule.makespan
        out.append({
            "part": "generated", "tasks": m, "robots": n, "seed": seed,
            "method": plan.method, "makespan": makespan, "solve_s": plan.elapsed_s,
            "exact_makespan": best.schedule.makespan, "exact_s": best.elapsed_s,
            "exact_proven": best.optimal, "greedy_makespan": greedy_makespan,
            "greedy_s": greedy_s, "lower_bound": bound,
            "gap": (makespan - bound) / makespan if makespan > 0 else 0.0,
            "vs_exact": makespan / best.schedule.makespan - 1.0,
            "vs_greedy": makespan / greedy_makespan - 1.0,
        })
    rows.extend(out)
    return out


def run(quick: bool, out_dir: Path) -> SectionReport:
    rows: list[Row] = []
    visible = _visible(rows)
    generated = _generated(rows, quick)
    anytime_s, exact_s = (QUICK_ANYTIME_S, QUICK_EXACT_S) if quick else (ANYTIME_S, EXACT_S)
    pct = "{:+.1%}".format
    tables = [
        Table(
            "The 12 visible MRTA-Benchmark instances (8 tasks, 3 robots): robocloud plan "
            "against the proven optimum",
            [Column("instance", "instance"), Column("optimum", "optimum", "{:.5f}"),
             Column("makespan", "makespan", "{:.5f}"),
             Column("difference", "difference", "{:+.1e}"),
             Column("proven", "proven optimal"), Column("solve_s", "solve s", "{:.2f}")],
            visible,
            note=CREDIT,
        ),
        Table(
            f"Generated missions: robocloud plan ({anytime_s:g} s) against CP-SAT exact "
            f"({exact_s:g} s) and the greedy baseline",
            [Column("tasks", "tasks"), Column("robots", "robots"), Column("seed", "seed"),
             Column("method", "method"), Column("makespan", "makespan", "{:.1f}"),
             Column("solve_s", "s", "{:.1f}"),
             Column("exact_makespan", "exact makespan", "{:.1f}"),
             Column("exact_s", "exact s", "{:.1f}"), Column("exact_proven", "proven"),
             Column("greedy_makespan", "greedy makespan", "{:.1f}"),
             Column("greedy_s", "greedy s", "{:.2f}"),
             Column("lower_bound", "lower bound", "{:.1f}"), Column("gap", "gap", "{:.1%}"),
             Column("vs_exact", "vs exact", pct), Column("vs_greedy", "vs greedy", pct)],
            generated,
            note="Instances drawn with the distributions of the " + CREDIT + " gap: "
            "(makespan - lower bound) / makespan, the bound the best of CP-SAT's and "
            "bounds.py's; vs: makespan / theirs - 1 (negative: robocloud plan is shorter).",
        ),
    ]
    optimal = all(abs(r["difference"]) <= 1e-3 for r in visible)
    slowest = max(r["solve_s"] for r in visible)
    goals = [
        Goal("the optimal makespan on the 12 visible instances",
             f"{sum(abs(r['difference']) <= 1e-3 for r in visible)} of 12 within 1e-3",
             optimal, f"largest difference {max(abs(r['difference']) for r in visible):.1e}"),
        Goal(f"each visible instance solved within {VISIBLE_GOAL_S:g} s",
             f"slowest {slowest:.2f} s", slowest <= VISIBLE_GOAL_S,
             f"{VISIBLE_GOAL_S - slowest:+.2f} s"),
    ]
    return SectionReport(
        name="missions",
        title="The mission planner (issue 29): MRTA-Benchmark instances and generated missions",
        rows=rows,
        tables=tables,
        notes=[CREDIT, "Solve times are inside the planner's child process, after a warm-up "
               "plan (the OR-Tools import is about 0.5 s of CPU on top)."],
        goals=goals,
    )
