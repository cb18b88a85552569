"""What ``select`` returns, in MODEL.md's output shape."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from robocloud.domain import Coalition

OptimizerName = Literal["exact", "mopso"]


@dataclass(frozen=True)
class SelectionResult:
    candidates: int
    ranking: tuple[str, ...]
    pareto: tuple[Coalition, ...]
    chosen: Coalition | None
    reason: str | None
    optimizer: OptimizerName
    elapsed_ms: float
    pool: tuple[str, ...] = ()

    def to_json(self) -> dict[str, Any]:
        """MODEL.md's ``select`` output."""
        return {
            "candidates": self.candidates,
            "ranking": list(self.ranking),
            "pareto": [c.to_json() for c in self.pareto],
            "chosen": self.chosen.to_json() if self.chosen else None,
            "reason": self.reason,
            "optimizer": self.optimizer,
            "elapsed_ms": round(self.elapsed_ms, 3),
        }
