"""The wildfire application's configuration: its IaaSs, its key, its forest, its units.

One settings object, built by the command (or a test) and handed to
``create_wildfire_app``; nothing is read from the environment at import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

# The simulator's forest (robocloud.sim.scenario draws robots over 2000 m x 2000 m).
DEFAULT_FOREST = (0.0, 0.0, 2000.0, 2000.0)
# Coordinates beyond this are typing mistakes, not forests (docs/model.md's positions are metres).
MAX_EXTENT = 1e7
MAX_CURRENCY_CHARS = 12


def _metres(value: float) -> str:
    return f"{value:,.0f}" if value == round(value) else f"{value:,.1f}"


@dataclass(frozen=True)
class Forest:
    """The area the application protects, in metres: a fire outside it is refused."""

    x0: float
    y0: float
    x1: float
    y1: float

    def __post_init__(self) -> None:
        values = (self.x0, self.y0, self.x1, self.y1)
        if not all(math.isfinite(v) and abs(v) <= MAX_EXTENT for v in values):
            raise ValueError(
                f"the forest's corners must be numbers of metres within ±{MAX_EXTENT:g}"
            )
        if not (self.x1 > self.x0 and self.y1 > self.y0):
            raise ValueError("the forest needs X0 < X1 and Y0 < Y1")

    @classmethod
    def parse(cls, text: str) -> Forest:
        """``"0,0,2000,2000"`` -> the forest from (0, 0) to (2000, 2000)."""
        parts = [p.strip() for p in text.split(",")]
        if len(parts) != 4:
            raise ValueError(f"{text!r} is not X0,Y0,X1,Y1")
        try:
            x0, y0, x1, y1 = (float(p) for p in parts)
        except ValueError:
            raise ValueError(f"{text!r} is not four numbers X0,Y0,X1,Y1") from None
        return cls(x0, y0, x1, y1)

    def contains(self, x: float, y: float) -> bool:
        return self.x0 <= x <= self.x1 and self.y0 <= y <= self.y1

    def span(self) -> str:
        return (
            f"x from {_metres(self.x0)} to {_metres(self.x1)} m and "
            f"y from {_metres(self.y0)} to {_metres(self.y1)} m"
        )

    def refusal(self, x: float, y: float, what: str = "fire") -> str | None:
        """The sentence refusing a fire (or ``what``) at (x, y); None when in the forest."""
        if self.contains(x, y):
            return None
        return (
            f"the {what} at ({_metres(x)}, {_metres(y)}) is outside the forest, "
            f"which spans {self.span()}."
        )

    def as_json(self) -> dict[str, float]:
        return {"x0": self.x0, "y0": self.y0, "x1": self.x1, "y1": self.y1}


@dataclass(frozen=True)
class WildfireSettings:
    """Everything ``robocloud wildfire`` is told.

    ``iaas`` lists the IaaSs in order of preference: requests go to the first
    that answers, the fleet is read from the first that answers, and every one
    is watched for health. They must all accept ``api_key``.
    """

    iaas: tuple[str, ...]
    api_key: str | None = None
    forest: Forest = field(default_factory=lambda: Forest(*DEFAULT_FOREST))
    currency: str = "credits"
    # Sends, cancels and reads on the operator's behalf wait this long.
    timeout: float = 10.0
    # The background poll of health, fleet and requests waits less: one slow
    # IaaS must not freeze the page's view of the others.
    poll_timeout: float = 3.0
    # How often the fleet, the clouds and the requests are read and pushed.
    tick: float = 1.0
    # A robot not heard from for this long is shown stale, greyed with its age.
    stale_after: float = 5.0
    # A page that hears nothing from this server for this long greys what it shows.
    silent_after: float = 5.0
    max_live_pages: int = 100

    def __post_init__(self) -> None:
        if not self.iaas:
            raise ValueError("at least one IaaS URL is needed")
        if len(set(self.iaas)) != len(self.iaas):
            raise ValueError("an IaaS URL is given twice")
        if not self.currency.strip() or len(self.currency) > MAX_CURRENCY_CHARS:
            raise ValueError(f"the currency label needs 1 to {MAX_CURRENCY_CHARS} characters")
        for name in ("timeout", "poll_timeout", "tick", "stale_after", "silent_after"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number of seconds")
