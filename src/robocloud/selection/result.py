"""What ``select`` returns, in docs/model.md's output shape plus how complete it is."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from robocloud.domain import Coalition
from robocloud.selection.exact import Bound

OptimizerName = Literal["exact", "mopso"]


@dataclass(frozen=True)
class SelectionResult:
    """docs/model.md's fields, then:

    - ``complete``: False when the time budget cut the search (or, with no
      coalition, when it ran out before the task was proven infeasible).
    - ``bound``: for the exact optimizer, how far ``pareto`` can be from the
      true front (all zero when complete); None for MOPSO (a heuristic, no
      certificate) and when nothing was found.
    - ``note``: a sentence saying what the budget cut and what the bound means.
    - ``searched``: False when a cheap test answered before any optimizer ran.
    - ``stages``: (stage, ms) for filtering (with the candidates' t_i and
      c_i), ranking and optimisation (everything after the ranking); not in
      the JSON output (``robocloud select --timings`` prints them).
    """

    candidates: int
    ranking: tuple[str, ...]
    pareto: tuple[Coalition, ...]
    chosen: Coalition | None
    reason: str | None
    optimizer: OptimizerName
    elapsed_ms: float
    pool: tuple[str, ...] = ()
    complete: bool = True
    bound: Bound | None = None
    note: str | None = None
    searched: bool = True
    stages: tuple[tuple[str, float], ...] = field(default=(), compare=False)

    def to_json(self) -> dict[str, Any]:
        """docs/model.md's ``select`` output, and ``complete``, ``bound`` and ``note``."""
        bound = self.bound
        return {
            "candidates": self.candidates,
            "ranking": list(self.ranking),
            "pareto": [c.to_json() for c in self.pareto],
            "chosen": self.chosen.to_json() if self.chosen else None,
            "reason": self.reason,
            "optimizer": self.optimizer,
            "elapsed_ms": round(self.elapsed_ms, 3),
            "complete": self.complete,
            "bound": (
                {"time": bound.time, "cost": bound.cost, "size": bound.size}
                if bound is not None
                else None
            ),
            "note": self.note,
        }
