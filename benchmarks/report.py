"""What a benchmark section hands back, and how it is printed and written.

A section is a function ``(quick, out_dir) -> SectionReport``. Its ``rows``
(flat dicts) go to ``<name>.csv`` as they are; its ``tables`` pick and format
columns of those rows for the terminal and for ``<name>.md``; its ``goals``
say what the issue asked for, what was measured and by how much it was met
or missed.
"""

from __future__ import annotations

import csv
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

Row = dict[str, Any]


@dataclass(frozen=True)
class Column:
    key: str
    header: str
    fmt: str | Callable[[Any], str] = "{}"

    def cell(self, row: Row) -> str:
        value = row.get(self.key)
        if value is None:
            return "n/a"
        if callable(self.fmt):
            return self.fmt(value)
        return self.fmt.format(value)


@dataclass(frozen=True)
class Table:
    title: str
    columns: Sequence[Column]
    rows: Sequence[Row]
    note: str = ""

    def cells(self) -> tuple[list[str], list[list[str]]]:
        headers = [c.header for c in self.columns]
        return headers, [[c.cell(r) for c in self.columns] for r in self.rows]


@dataclass(frozen=True)
class Goal:
    goal: str
    measured: str
    met: bool | None  # None: not measured in this run
    margin: str

    @property
    def verdict(self) -> str:
        return {True: "met", False: "MISSED", None: "not measured"}[self.met]


@dataclass
class SectionReport:
    name: str
    title: str
    rows: list[Row]
    tables: list[Table] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    goals: list[Goal] = field(default_factory=list)
    figures: list[Path] = field(default_factory=list)


def _goal_table(goals: Sequence[Goal]) -> tuple[list[str], list[list[str]]]:
    return (["goal", "measured", "verdict", "margin"],
            [[g.goal, g.measured, g.verdict, g.margin] for g in goals])


def text_table(headers: Sequence[str], body: Sequence[Sequence[str]]) -> str:
    """A plain-text table: numbers right-aligned, text left-aligned."""
    widths = [max(len(h), *(len(r[i]) for r in body)) if body else len(h)
              for i, h in enumerate(headers)]

    def numeric(s: str) -> bool:
        return s.replace(".", "", 1).replace("-", "", 1).replace(",", "").replace("x", "").isdigit()

    def line(cells: Sequence[str]) -> str:
        return "  ".join(c.rjust(w) if numeric(c) else c.ljust(w)
                         for c, w in zip(cells, widths, strict=True)).rstrip()

    rule = "  ".join("-" * w for w in widths)
    return "\n".join([line(headers), rule, *(line(r) for r in body)])


def markdown_table(headers: Sequence[str], body: Sequence[Sequence[str]]) -> str:
    def line(cells: Sequence[str]) -> str:
        return "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"

    return "\n".join([line(headers), "|" + "|".join("---" for _ in headers) + "|",
                      *(line(r) for r in body)])


def render_text(report: SectionReport) -> str:
    parts = [f"== {report.title} =="]
    parts += report.notes
    for table in report.tables:
        parts += ["", table.title, text_table(*table.cells())]
        if table.note:
            parts.append(table.note)
    if report.goals:
        parts += ["", "Goals", text_table(*_goal_table(report.goals))]
    for figure in report.figures:
        parts.append(f"figure: {figure}")
    return "\n".join(parts)


def render_markdown(report: SectionReport, machine: Sequence[tuple[str, str]]) -> str:
    parts = [f"# {report.title}", ""]
    parts += [*report.notes, ""] if report.notes else []
    for table in report.tables:
        parts += [f"## {table.title}", "", markdown_table(*table.cells()), ""]
        if table.note:
            parts += [table.note, ""]
    if report.goals:
        parts += ["## Goals", "", markdown_table(*_goal_table(report.goals)), ""]
    for figure in report.figures:
        parts += [f"![{figure.stem}]({figure.name})", ""]
    parts += ["## Machine", "", markdown_table(["", ""], [[k, v] for k, v in machine]), ""]
    return "\n".join(parts)


def write_csv(path: Path, rows: Sequence[Row]) -> None:
    keys: list[str] = []
    for row in rows:
        keys += [k for k in row if k not in keys]
    with path.open("w", newline="") as out:
        writer = csv.DictWriter(out, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)
