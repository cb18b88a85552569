"""Which robot each request follows or claims now, and which robots are set aside.

The one owner of robots' routes and claims in an IaaS (``RobotRoutes``):

- a **route** says which request a robot's reports go to: from the robot's
  reservation (``Follow``) until its part ends (``Unfollow``, or the request's
  end). A mission (``robocloud.iaas.missions``) routes its robots the same
  way, to the mission's id, for the robot's whole part of the mission, and
  says which of its tasks the robot was last sent (``working_on``): the one
  request id the robot may work on without being a stray;
- a **claim** keeps a robot that a selection has just chosen away from the
  other selections until its reservation is decided: from the choice until
  the reservation's answer (``Unclaim``), the request's end, whichever comes
  first. Once reserved, the store's reservation and the route keep it;
- a robot **set aside** failed its last ``STRIKES`` requests in a row the same
  ways (no ack within the deadline, no progress, past its expected finish):
  no selection of this cloud chooses it until its cool-down ends. One part
  done clears its record.

"Who may be chosen now" is everyone but ``held()``. Written on the event
loop's thread; ``robots_of`` and ``aside`` are also read from the overlay's
threads (another cloud asking which of its robots still work for a request),
hence the lock.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from robocloud.domain.mission_ids import MISSION_ID

STRIKES = 2  # failures in a row that set a robot aside


@dataclass(frozen=True)
class SetAside:
    """A robot no selection chooses until ``until`` (unix time), and why."""

    until: float
    why: str


class RobotRoutes:
    def __init__(
        self,
        cooldown: float = 300.0,
        wall: Callable[[], float] = time.time,
    ) -> None:
        self.cooldown = cooldown
        self._wall = wall
        self._lock = threading.Lock()
        self._routes: dict[str, str] = {}  # robot -> the request that follows it
        self._claims: dict[str, str] = {}  # robot -> the request that chose it, not reserved yet
        self._tasks: dict[str, str] = {}  # robot -> the mission task it was last sent
        self._by_request: dict[str, set[str]] = {}  # request -> its routed and claimed robots
        self._strikes: dict[str, list[str]] = {}  # robot -> its failures in a row, why
        self._aside: dict[str, SetAside] = {}

    # -- routes and claims ---------------------------------------------------------

    def follow(self, request_id: str, robot: str, task: str | None = None) -> bool:
        """Route the robot's reports to the request; False when it already was.

        ``task``: a mission's, the request id of the task the robot is sent now.
        """
        with self._lock:
            if task is None:
                self._tasks.pop(robot, None)
            else:
                self._tasks[robot] = task
            if self._routes.get(robot) == request_id:
                return False
            self._drop(self._routes, robot)
            self._routes[robot] = request_id
            self._by_request.setdefault(request_id, set()).add(robot)
            return True

    def take(self, request_id: str, robots: Iterable[str]) -> list[str]:
        """Follow every robot for the request, unless another holds one: then none,
        and the robots held (routed, claimed or set aside) are returned."""
        robots = list(robots)
        with self._lock:
            now = self._wall()
            taken = [
                r
                for r in robots
                if self._routes.get(r, request_id) != request_id
                or self._claims.get(r, request_id) != request_id
                or (r in self._aside and self._aside[r].until > now)
            ]
            if taken:
                return taken
            for robot in robots:
                self._routes[robot] = request_id
                self._by_request.setdefault(request_id, set()).add(robot)
            return []

    def unfollow(self, request_id: str, robot: str) -> bool:
        """End the robot's route (and claim) for the request; False when it had none."""
        with self._lock:
            if self._claims.get(robot) == request_id:
                self._drop(self._claims, robot)
            if self._routes.get(robot) != request_id:
                return False
            self._drop(self._routes, robot)
            self._tasks.pop(robot, None)
            return True

    def claim(self, request_id: str, robots: Iterable[str]) -> None:
        with self._lock:
            for robot in robots:
                self._drop(self._claims, robot)
                self._claims[robot] = request_id
                self._by_request.setdefault(request_id, set()).add(robot)

    def unclaim(self, request_id: str, robots: Iterable[str]) -> None:
        with self._lock:
            for robot in robots:
                if self._claims.get(robot) == request_id:
                    self._drop(self._claims, robot)

    def forget(self, request_id: str) -> None:
        """The request's actor has ended: none of its routes and claims is left."""
        with self._lock:
            for robot in self._by_request.pop(request_id, set()):
                if self._routes.get(robot) == request_id:
                    del self._routes[robot]
                    self._tasks.pop(robot, None)
                if self._claims.get(robot) == request_id:
                    del self._claims[robot]

    def request_of(self, robot: str) -> str | None:
        """The request that follows the robot now."""
        return self._routes.get(robot)

    def working_on(self, robot: str) -> str | None:
        """The request id the robot may work on now: its mission task's, or its request's."""
        return self._tasks.get(robot) or self._routes.get(robot)

    def kept_by_missions(self) -> set[str]:
        """The robots this cloud's missions hold now (any thread)."""
        with self._lock:
            return {r for r, q in self._routes.items() if MISSION_ID.fullmatch(q)}

    def claimed_by(self, robot: str) -> str | None:
        return self._claims.get(robot)

    def robots_of(self, request_id: str) -> list[str]:
        """The robots a request follows or has chosen now (any thread)."""
        with self._lock:
            return sorted(self._by_request.get(request_id, ()))

    def held(self) -> set[str]:
        """Robots no selection may choose now: followed, claimed, or set aside."""
        with self._lock:
            held = self._routes.keys() | self._claims.keys()
            if self._aside:
                now = self._wall()
                held |= {r for r, a in self._aside.items() if a.until > now}
            return held

    def _drop(self, table: dict[str, str], robot: str) -> None:
        """Remove ``robot`` from ``table`` (the lock held), and from its request's set."""
        request_id = table.pop(robot, None)
        if request_id is None:
            return
        other = self._claims if table is self._routes else self._routes
        if other.get(robot) == request_id:
            return  # still the request's through the other table
        robots = self._by_request.get(request_id)
        if robots is not None:
            robots.discard(robot)
            if not robots:
                del self._by_request[request_id]

    # -- robots that keep failing ------------------------------------------------------

    def strike(self, robot: str, why: str) -> SetAside | None:
        """The robot failed a request so; the set-aside it earns now, if any."""
        with self._lock:
            strikes = self._strikes.setdefault(robot, [])
            strikes.append(why)
            if len(strikes) < STRIKES:
                return None
            del self._strikes[robot]
            aside = SetAside(
                until=self._wall() + self.cooldown,
                why=f"it failed {len(strikes)} requests in a row: {'; '.join(strikes)}",
            )
            self._aside[robot] = aside
            self._prune()
            return aside

    def behaved(self, robot: str) -> None:
        """The robot finished its part: its failures in a row start again from none."""
        if robot in self._strikes:
            with self._lock:
                self._strikes.pop(robot, None)

    def aside(self, robot: str) -> SetAside | None:
        """Why and until when the robot is set aside, if it is now."""
        aside = self._aside.get(robot)
        if aside is None or aside.until <= self._wall():
            return None
        return aside

    def _prune(self) -> None:
        """Forget set-asides that are over (the lock held); bounded by the fleet anyway."""
        now = self._wall()
        for robot in [r for r, a in self._aside.items() if a.until <= now]:
            del self._aside[robot]
        if len(self._strikes) > 100_000:
            self._strikes.clear()
