"""The hard bounds on what a home lends one origin (``robocloud.federation.home.Home.reserve``).

A trusted cloud may still ask too much: every robot, for ever, busy and
charging ones included. Whatever it asks, the home lends:

- **for at most ``lease_max`` from the first reservation** of a robot by the
  origin, until the home forwards the robot's dispatch: reserving again,
  under another request id or after a release, renews nothing past that;
  the robot is the origin's again only after ``lease_max`` without a lease
  (``Undispatched``);
- **only robots that could work now**: idle, heard from, with at least
  ``LEND_MIN_BATTERY`` percent (``unfit``), and not set aside by the home
  itself (``set_aside``: they failed its own requests too often lately);
- **at most a share of its fleet to one origin** at a time (``over_share``,
  ``--lend-share``);
- **at a bounded rate**: ``RESERVE_RATE`` reservations a second per origin,
  in bursts of ``RESERVE_BURST`` (``ReserveRate``), so a peer re-reserving in
  a loop is refused rather than served.

Each refusal is a sentence the origin receives and the home logs.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Mapping, Sequence
from typing import Protocol

from robocloud.domain import Robot

LEND_MIN_BATTERY = 20.0  # percent: a robot lent must be able to go somewhere
LEND_SHARE = 0.5  # of this cloud's robots one origin may hold at once
# Reservations a second per origin, on average, and at once: far above what a
# busy origin sends (one per request, a few more when a robot was taken
# meanwhile), far below a loop.
RESERVE_RATE = 50.0
RESERVE_BURST = 200


def unfit(robots: Sequence[str], fleet: Mapping[str, Robot], min_battery: float) -> str | None:
    """Why some of ``robots`` cannot be lent now (not idle, silent, low battery), or None."""
    reasons = []
    for robot_id in robots:
        robot = fleet.get(robot_id)
        if robot is None:
            continue  # unknown robots are refused elsewhere, with their own sentence
        if robot.status != "idle":
            reasons.append(f"{robot_id} is {robot.status}")
        elif robot.battery < min_battery:
            reasons.append(f"{robot_id} has {robot.battery:g}% of battery")
        if len(reasons) == 5:
            break
    if not reasons:
        return None
    return (
        f"only idle robots with at least {min_battery:g}% of battery are lent: "
        f"{'; '.join(reasons)}."
    )


class Aside(Protocol):
    """A robot its home set aside now (``robocloud.iaas.routes.SetAside``): why."""

    @property
    def why(self) -> str: ...


def never_aside(robot: str) -> Aside | None:
    """No robot is set aside (a home that keeps no record of failures)."""
    return None


def set_aside(robots: Sequence[str], aside: Callable[[str], Aside | None], home: str) -> str | None:
    """Why some of ``robots`` cannot be lent: ``home`` set them aside, or None.

    A robot that keeps failing the home's own requests is not chosen by them
    for a while; it is not lent to another cloud's either.
    """
    for robot in robots:
        now = aside(robot)
        if now is not None:
            return f"{home} has set {robot} aside and lends it to no one now: {now.why}."
    return None


def over_share(
    origin: str, held: int, asking: int, fleet: int, share: float, home: str
) -> str | None:
    """Why lending ``asking`` more robots to ``origin``, which holds ``held``, is too many."""
    most = math.floor(fleet * share)
    if held + asking <= most:
        return None
    return (
        f"{origin} holds {held} of {home}'s {fleet} robots and asks {asking} more; "
        f"{home} lends one cloud at most {share:.0%} of its robots ({most})."
    )


class ReserveRate:
    """A token bucket per origin: ``rate`` reservations a second, ``burst`` at once."""

    def __init__(
        self, clock: Callable[[], float], rate: float = RESERVE_RATE, burst: int = RESERVE_BURST
    ) -> None:
        self._clock = clock
        self.rate = rate
        self.burst = burst
        self._lock = threading.Lock()
        self._buckets: dict[str, tuple[float, float]] = {}  # origin -> (tokens, when)

    def take(self, origin: str) -> str | None:
        """None when ``origin`` may reserve now (a token is taken), else why not."""
        if math.isinf(self.rate):
            return None  # no bound (tests of many loans at once)
        now = self._clock()
        with self._lock:
            tokens, then = self._buckets.get(origin, (float(self.burst), now))
            tokens = min(float(self.burst), tokens + (now - then) * self.rate)
            if tokens < 1.0:
                self._buckets[origin] = (tokens, now)
                return (
                    f"{origin} reserves too often: at most {self.rate:g} reservations a second "
                    f"(bursts of {self.burst}); try again in {(1.0 - tokens) / self.rate:.1f} s."
                )
            self._buckets[origin] = (tokens - 1.0, now)
            return None


class Undispatched:
    """How long each origin has held each robot leased and not dispatched, without a break.

    A run of leases of one robot to one origin goes on while each
    reservation comes within ``lease_max`` of the end of the lease before
    (whatever the request id, released or lapsed in between); it ends with
    the robot's dispatch. A run lasts at most ``lease_max`` seconds: an origin
    cannot keep a robot it does not use by reserving it again. Memory: at
    most one entry per robot and origin, pruned once the run is over.
    """

    def __init__(self, home: str, lease_max: float, clock: Callable[[], float]) -> None:
        self.home = home
        self.lease_max = lease_max
        self._clock = clock
        self._lock = threading.Lock()
        self._runs: dict[tuple[str, str], tuple[float, float]] = {}  # -> (began, lease ends)
        self._pruned = clock()

    def grant(self, origin: str, robots: Sequence[str], asked: float) -> tuple[float, str | None]:
        """(the lease to grant for ``robots`` now, or why none is); ``record`` it once lent."""
        now = self._clock()
        with self._lock:
            if now - self._pruned > self.lease_max:
                self._prune(now)
            began = min((self._began(origin, robot, now) for robot in robots), default=now)
        lease = min(asked, self.lease_max - (now - began))
        if lease <= 0:
            return 0.0, (
                f"{origin} has held {', '.join(robots[:5])} leased and not dispatched "
                f"for {now - began:.0f} s: {self.home} leases at most {self.lease_max:g} s "
                f"until the dispatch, renewals included; again {self.lease_max:g} s after "
                "the lease ends."
            )
        return lease, None

    def record(self, origin: str, robots: Sequence[str], lease: float) -> None:
        """The robots were lent to ``origin`` for ``lease`` seconds from now."""
        now = self._clock()
        with self._lock:
            for robot in robots:
                self._runs[(origin, robot)] = (self._began(origin, robot, now), now + lease)

    def _began(self, origin: str, robot: str, now: float) -> float:
        """When the run of ``robot``'s leases to ``origin`` began (now: none goes on)."""
        run = self._runs.get((origin, robot))
        return run[0] if run is not None and now - run[1] <= self.lease_max else now

    def dispatched(self, origin: str, robot: str) -> None:
        """The home forwarded the robot's dispatch for ``origin``: its run is over."""
        with self._lock:
            self._runs.pop((origin, robot), None)

    def _prune(self, now: float) -> None:
        self._pruned = now
        self._runs = {key: run for key, run in self._runs.items() if now - run[1] <= self.lease_max}
