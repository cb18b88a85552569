"""Robots are always told: a robot working for a request that does not need it is stopped.

A robot of this cloud that reports working on a request that is not active
for it (neither one of this cloud's requests that follows it, nor the task
of this cloud's mission it was last sent, nor a loan to another cloud for that
request or mission) is told to stop, at once and then at most
once every ``TELL_AGAIN_AFTER`` seconds while it keeps at it (``StrayRobots``).
The stops of a request's own life (a robot failed, refused, or the request
ended) are its actor's; this catches what they missed: a stop the robot did
not hear, a command it took late, a robot back from a crash with an old task.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Awaitable, Callable, Coroutine
from typing import Any

from robocloud.domain.mission_ids import holder_of
from robocloud.fleet.link import RobotLink
from robocloud.fleet.messages import State
from robocloud.iaas.metrics import IaasMetrics
from robocloud.iaas.routes import RobotRoutes

log = logging.getLogger(__name__)

WORKING = frozenset({"travel", "waiting", "work"})
TELL_AGAIN_AFTER = 1.0  # seconds between two stop commands to a robot for one request


class StrayRobots:
    def __init__(
        self,
        cloud: str,
        link: RobotLink,
        routes: RobotRoutes,
        lent_for: Callable[[str], str | None],
        blocking: Callable[..., Awaitable[Any]],
        spawn: Callable[[Coroutine[Any, Any, Any], str], object],
        metrics: IaasMetrics,
        mono: Callable[[], float] = time.monotonic,
    ) -> None:
        self.cloud = cloud
        self.link = link
        self.routes = routes
        self.lent_for = lent_for
        self.blocking = blocking
        self.spawn = spawn
        self.metrics = metrics
        self.mono = mono
        self._told: dict[tuple[str, str], float] = {}  # (robot, request) -> when told to stop

    @staticmethod
    def may_be_stray(state: State, cloud: str) -> bool:
        """Whether a state could be a stray's (cheap, on Zenoh's threads)."""
        task = state.task
        return task is not None and task.phase in WORKING and state.cloud == cloud

    def check(self, state: State) -> None:
        """A state of this cloud's robot (on the loop): tell it to stop if it is a stray."""
        task = state.task
        if (
            task is not None
            and task.phase in WORKING
            and state.cloud == self.cloud
            and task.request_id != self.routes.working_on(state.id)
        ):
            self._tell_to_stop(state.id, task.request_id)

    def _tell_to_stop(self, robot: str, request_id: str) -> None:
        now = self.mono()
        key = (robot, request_id)
        if now - self._told.get(key, -TELL_AGAIN_AFTER) < TELL_AGAIN_AFTER:
            return
        self._told[key] = now
        if len(self._told) > 1000:  # bounded: forget what is long past
            self._told = {k: t for k, t in self._told.items() if now - t < 10 * TELL_AGAIN_AFTER}
        self.spawn(self._stop(robot, request_id), f"telling robot {robot} to stop")

    async def _stop(self, robot: str, request_id: str) -> None:
        if not self._works_for(robot, request_id):
            return  # a report that was overtaken: the robot has moved on
        if await self.blocking(self.lent_for, robot) == holder_of(request_id):
            return  # lent to another cloud for that request (or mission)
        if self.routes.working_on(robot) == request_id or not self._works_for(robot, request_id):
            return  # followed, or done, meanwhile
        log.warning(
            "robot %s reports work on request %s, which is not active for it; telling it to stop",
            robot,
            request_id,
        )
        self.metrics.stops.labels("stray").inc()
        await self.blocking(self.link.cancel, robot, request_id)

    def _works_for(self, robot: str, request_id: str) -> bool:
        """Whether the robot's latest state says it is working on the request."""
        state = self.link.state(robot)
        task = state.task if state is not None else None
        return task is not None and task.request_id == request_id and task.phase in WORKING
