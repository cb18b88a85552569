"""Where the tests find the MRTA-Benchmark's visible instances.

The MRTA-Benchmark dataset is by Jakob Bichler (TU Delft, Autonomous
Multi-Robot Lab), DOI 10.4121/10e28ee0-9ad9-450d-8be7-6e6a91f2931f, licensed
CC BY 4.0 (https://creativecommons.org/licenses/by/4.0/); made for the paper
"SADCHER: Scheduling using Attention-based Dynamic Coalitions of
Heterogeneous Robots in Real-Time" (Bichler, Matoses Gimenez, Alonso-Mora,
arXiv:2510.14851). The files are not in this repository: they are read from
``shared/mrta`` beside the clone (``../shared/mrta``), as in CI; from a git
worktree, beside the main clone. A missing folder fails the tests with a
sentence: they are never skipped.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]


def _candidates() -> list[Path]:
    places = []
    if os.environ.get("ROBOCLOUD_MRTA_DIR"):
        places.append(Path(os.environ["ROBOCLOUD_MRTA_DIR"]))
    places.append(ROOT.parent / "shared" / "mrta")
    git = ROOT / ".git"
    if git.is_file():  # a worktree: .git says where the main clone's .git is
        text = git.read_text().strip()
        if text.startswith("gitdir:"):
            main_git = Path(text.split(":", 1)[1].strip()).resolve()
            # <main>/.git/worktrees/<name> -> <main>
            places.append(main_git.parents[2].parent / "shared" / "mrta")
    return places


def mrta_dir() -> Path:
    for place in _candidates():
        if (place / "visible" / "manifest.json").is_file():
            return place
    tried = ", ".join(str(p) for p in _candidates())
    raise AssertionError(
        f"the MRTA-Benchmark files are missing: no visible/manifest.json in {tried}. "
        "Put the shared/ folder beside the clone (as in CI) or set ROBOCLOUD_MRTA_DIR."
    )


def visible() -> list[tuple[str, dict[str, Any], dict[str, Any], float]]:
    """(id, instance, optimal schedule, optimal makespan) of each visible instance."""
    folder = mrta_dir() / "visible"
    manifest = json.loads((folder / "manifest.json").read_text())
    return [
        (
            row["id"],
            json.loads((folder / row["instance"]).read_text()),
            json.loads((folder / row["solution"]).read_text()),
            row["optimal_makespan"],
        )
        for row in manifest["instances"]
    ]
