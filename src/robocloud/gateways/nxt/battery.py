"""The brick's battery: GETBATTERYLEVEL's millivolts as the percent robocloud reports.

The NXT only tells its voltage. The curves are straight lines between an
"empty" and a "full" voltage, clamped to 0..100 %:

==================  ========  ========  =================================================
battery             full      empty     why
==================  ========  ========  =================================================
six AA cells        9000 mV   6500 mV   fresh alkaline cells are 1.5 V each; at about
``"aa"``                                1.08 V a cell the motors lose their torque
rechargeable pack   8200 mV   7000 mV   the NXT's Li-ion pack (two cells, 7.4 V nominal):
``"rechargeable"``                      4.1 V a cell charged, 3.5 V a cell nearly flat
==================  ========  ========  =================================================

A line is crude: an alkaline cell's voltage falls fast at first, then slowly,
so the percent reads low early in a set of cells' life; the voltage also sags
under load, so the gateway reads it with the motors stopped when it can.
"""

from __future__ import annotations

from typing import Literal

CURVES: dict[str, tuple[int, int]] = {"aa": (6500, 9000), "rechargeable": (7000, 8200)}


def percent(millivolts: int, battery: Literal["aa", "rechargeable"]) -> float:
    empty, full = CURVES[battery]
    share = (millivolts - empty) / (full - empty)
    return round(min(max(share, 0.0), 1.0) * 100.0, 1)
