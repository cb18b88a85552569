"""The wildfire scenario of the thesis (section 5.4, "Illustrative Scenario").

A fleet of heterogeneous robots, owned by several clouds, is deployed in a
forest; a fire breaks out and the Wildfire Suppression Application asks for
a time-critical coalition: at most 50 robots, at most 500, within 10 minutes,
batteries above 70%. Of the 1000 robots of the thesis, 100 meet the filter.

The robots are LEGO Mindstorms NXT-like, as in the thesis's prototype
(section 6.1.2): the Tribot, whose arms grab the extinguisher (actuating
``grabber``), and the base type, which kicks obstacles away (actuating
``kicker``). Each carries a random non-empty subset of the NXT sensors
(``light``, ``ultrasonic``, ``sound``, ``touch``), so capability sets vary.

The distributions (choice):

- forest 2000 m x 2000 m, robots uniform over it; the fire uniform over the
  central 1000 m x 1000 m, so that some robots reach it in time wherever it is;
- half Tribots, half base robots; each sensor present independently, light
  and ultrasonic with probability 0.25, sound 0.5, touch 0.6, and a robot
  drawn with none gets one of the four at random;
- speed uniform 0.5-2 m/s; travel cost 0.02-0.1 per metre, higher for the
  faster robots (loosely: the speed's quantile plus normal noise of 0.2);
- sensing: time 10-60 s, cost 0.5-3; actuating: time 60-180 s, cost 4-15;
  each a uniform "quality" q: time falls with q, cost rises with it (with the
  same noise), so a quicker tool is a dearer one;
- status, in exact shares: 10% idle with battery 70-100 (the candidates),
  15% idle with battery below 70, 30% busy, 15% charging, 15% reserved,
  15% offline.

Every shape scales with ``robots``: the forest stays the same and the shares
stay exact, so 100 000 robots give 10 000 candidates. Everything is drawn with
``numpy.random.default_rng`` from ``seed``: the same seed gives the same JSON.

What these give at 1000 robots, seeds 0 to 9 (exact front): 100 candidates,
23 to 38 of them reach the fire within 600 s, the request is always feasible
(cheapest coalition 46 to 84), and the front has 3 to 6 members trading time
against cost; for seeds 0, 1 and 3 it also trades size (3 or 4 robots).
"""

from __future__ import annotations

import gc
import string
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import numpy.typing as npt

from robocloud.errors import InvalidInput

FOREST_SIZE = 2000.0  # metres, square
SENSORS: tuple[str, ...] = ("light", "ultrasonic", "sound", "touch")
# (kind name, its actuating capability): the Tribot and the NXT base type.
KINDS: tuple[tuple[str, str], ...] = (("tribot", "grabber"), ("base", "kicker"))
MAX_CLOUDS = len(string.ascii_lowercase)

# Each sensor independently, in SENSORS order; a robot drawn with none gets
# one at random. The two the task needs are the scarce ones, so a coalition
# sometimes does better with one robot more than the smallest it could field.
SENSOR_PROBABILITY: tuple[float, ...] = (0.25, 0.25, 0.5, 0.6)
# Spread of the loose correlations below, on a 0-1 quality scale.
JITTER = 0.2

SPEED = (0.5, 2.0)
TRAVEL_COST_PER_M = (0.02, 0.1)
SENSING_TIME = (10.0, 60.0)
SENSING_COST = (0.5, 3.0)
ACTUATING_TIME = (60.0, 180.0)
ACTUATING_COST = (4.0, 15.0)

# Status shares; "ready" is idle with a battery that passes the task's filter.
READY_SHARE = 0.10
STATUS_SHARES: tuple[tuple[str, float], ...] = (
    ("ready", READY_SHARE),
    ("idle-low", 0.15),
    ("busy", 0.30),
    ("charging", 0.15),
    ("reserved", 0.15),
    ("offline", 0.15),
)
MIN_BATTERY = 70.0

# Independent streams, so the task does not depend on how many robots there are.
_ROBOT_STREAM = 0
_TASK_STREAM = 1

FloatArray = npt.NDArray[np.float64]


def cloud_names(clouds: int) -> list[str]:
    """``cloud-a``, ``cloud-b``, ... for ``clouds`` clouds (1 to 26)."""
    _check_counts(1, clouds)
    return [f"cloud-{letter}" for letter in string.ascii_lowercase[:clouds]]


def wildfire_scenario(robots: int = 1000, clouds: int = 3, seed: int = 0) -> dict[str, Any]:
    """docs/model.md's ``select`` input for the thesis's wildfire scenario."""
    return {
        "robots": wildfire_robots(robots, clouds, seed),
        "task": wildfire_task(seed),
    }


def wildfire_task(seed: int = 0) -> dict[str, Any]:
    """The thesis's request: time critical, 50 robots, 500, 10 minutes, battery > 70%."""
    _check_seed(seed)
    rng = np.random.default_rng([seed, _TASK_STREAM])
    low, high = FOREST_SIZE / 4, 3 * FOREST_SIZE / 4
    location = np.round(rng.uniform(low, high, size=2), 1)
    return {
        "location": [float(v) for v in location],
        "sensing": {"light": 1, "ultrasonic": 1},
        "actuating": {"grabber": 2, "kicker": 1},
        "max_robots": 50,
        "max_cost": 500.0,
        "max_time": 600.0,
        "min_battery": MIN_BATTERY,
        "priority": "time",
        "execution": "parallel",
    }


@contextmanager
def _collector_paused() -> Iterator[None]:
    """No cyclic garbage collection while millions of lists and dicts are made.

    They hold no cycles, and each collection would walk all those made so
    far: paused, a million robots take half the time.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


@_collector_paused()
def wildfire_robots(robots: int = 1000, clouds: int = 3, seed: int = 0) -> list[dict[str, Any]]:
    """``robots`` robots as JSON dicts valid for ``robocloud.domain.Robot``.

    Robots are grouped by cloud, in order; the clouds' sizes differ by at most
    one. Ids are the cloud's letter and a number from 1, zero-padded to at
    least 4 digits (``a-0001``).
    """
    _check_counts(robots, clouds)
    _check_seed(seed)
    rng = np.random.default_rng([seed, _ROBOT_STREAM])
    n = robots

    # Everything is drawn for every robot in a fixed order, whatever a robot
    # ends up carrying, so a seed always means the same stream.
    position = np.round(rng.uniform(0.0, FOREST_SIZE, size=(n, 2)), 1)
    speed_q = rng.uniform(0.0, 1.0, size=n)
    speed = np.round(_scale(speed_q, SPEED), 2)
    # Faster robots spend more per metre: time and cost pull apart.
    travel = np.round(_scale(_jitter(rng, speed_q), TRAVEL_COST_PER_M), 3)
    kind = rng.integers(0, len(KINDS), size=n)
    has_sensor = rng.random((n, len(SENSORS))) < np.array(SENSOR_PROBABILITY)
    fallback = rng.integers(0, len(SENSORS), size=n)
    bare = ~has_sensor.any(axis=1)
    has_sensor[bare, fallback[bare]] = True
    # A better tool is quicker and dearer, again a trade-off.
    sensing_q = rng.uniform(0.0, 1.0, size=(n, len(SENSORS)))
    sensing_time = np.round(_scale(1.0 - sensing_q, SENSING_TIME), 1)
    sensing_cost = np.round(_scale(_jitter(rng, sensing_q), SENSING_COST), 2)
    actuating_q = rng.uniform(0.0, 1.0, size=n)
    actuating_time = np.round(_scale(1.0 - actuating_q, ACTUATING_TIME), 1)
    actuating_cost = np.round(_scale(_jitter(rng, actuating_q), ACTUATING_COST), 2)
    status, battery = _statuses(rng, n)

    per_cloud = _split(n, clouds)
    names = cloud_names(clouds)
    width = max(4, len(str(max(per_cloud))))
    ids: list[str] = []
    homes: list[str] = []
    for letter, name, count in zip(string.ascii_lowercase, names, per_cloud, strict=False):
        ids.extend(f"{letter}-{number:0{width}d}" for number in range(1, count + 1))
        homes.extend([name] * count)

    # Python lists, so the dicts hold plain floats and ints for JSON.
    positions = position.tolist()
    speeds = speed.tolist()
    travels = travel.tolist()
    kinds = kind.tolist()
    sensors = has_sensor.tolist()
    s_time = sensing_time.tolist()
    s_cost = sensing_cost.tolist()
    a_time = actuating_time.tolist()
    a_cost = actuating_cost.tolist()
    statuses = status.tolist()
    batteries = battery.tolist()

    fleet: list[dict[str, Any]] = []
    for i in range(n):
        capabilities: dict[str, dict[str, Any]] = {}
        for j, sensor in enumerate(SENSORS):
            if sensors[i][j]:
                capabilities[sensor] = {
                    "kind": "sensing",
                    "time": s_time[i][j],
                    "cost": s_cost[i][j],
                }
        capabilities[KINDS[kinds[i]][1]] = {
            "kind": "actuating",
            "time": a_time[i],
            "cost": a_cost[i],
        }
        fleet.append(
            {
                "id": ids[i],
                "cloud": homes[i],
                "position": positions[i],
                "speed": speeds[i],
                "battery": batteries[i],
                "status": statuses[i],
                "travel_cost_per_m": travels[i],
                "capabilities": capabilities,
            }
        )
    return fleet


def _statuses(rng: np.random.Generator, n: int) -> tuple[npt.NDArray[np.str_], FloatArray]:
    """Statuses in exact shares, shuffled; batteries to match each status."""
    counts = [int(n * share) for _, share in STATUS_SHARES]
    # The rounding remainder goes to "busy", so "ready" is exactly floor(10%).
    counts[2] += n - sum(counts)
    labels = np.repeat(np.array([label for label, _ in STATUS_SHARES]), counts)
    labels = labels[rng.permutation(n)]
    battery = np.round(rng.uniform(5.0, 100.0, size=n), 1)
    ready = labels == "ready"
    battery[ready] = np.round(rng.uniform(MIN_BATTERY, 100.0, size=int(ready.sum())), 1)
    low = labels == "idle-low"
    # Strictly under the filter: at most 69.9 after rounding to 0.1.
    battery[low] = np.round(rng.uniform(5.0, MIN_BATTERY - 0.1, size=int(low.sum())), 1)
    charging = labels == "charging"
    battery[charging] = np.round(rng.uniform(5.0, 60.0, size=int(charging.sum())), 1)
    status = np.where(ready | low, "idle", labels)
    return status, battery


def _scale(q: FloatArray, bounds: tuple[float, float]) -> FloatArray:
    low, high = bounds
    return low + (high - low) * q


def _jitter(rng: np.random.Generator, q: FloatArray) -> FloatArray:
    """``q`` with some noise, kept in [0, 1]: a loose, not exact, correlation."""
    return np.clip(q + rng.normal(0.0, JITTER, size=q.shape), 0.0, 1.0)


def _split(n: int, parts: int) -> list[int]:
    base, extra = divmod(n, parts)
    return [base + (1 if k < extra else 0) for k in range(parts)]


def _check_counts(robots: int, clouds: int) -> None:
    if robots < 1:
        raise InvalidInput(f"robots must be at least 1, not {robots}.", field="robots")
    if not 1 <= clouds <= MAX_CLOUDS:
        raise InvalidInput(
            f"clouds must be between 1 and {MAX_CLOUDS}, not {clouds}.", field="clouds"
        )


def _check_seed(seed: int) -> None:
    if seed < 0:
        raise InvalidInput(f"seed must be 0 or more, not {seed}.", field="seed")
