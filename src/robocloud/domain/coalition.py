"""A coalition: a set of robots and its objectives T (time), C (cost), N (size)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True, order=False)
class Coalition:
    robots: tuple[str, ...]  # sorted ids
    time: float
    cost: float

    @property
    def size(self) -> int:
        return len(self.robots)

    def to_json(self) -> dict[str, Any]:
        return {
            "robots": list(self.robots),
            "time": self.time,
            "cost": self.cost,
            "size": self.size,
        }
