"""What this cloud answers to the other clouds about its own robots (its ``HomeDesk``).

A robot is reserved only at its home: for a request of another cloud (the
origin) the home keeps a shadow request in its own store, application
``cloud:<origin>`` and idempotency key the origin's request id, so the
store's reservations (one robot, one active request) cover the whole
federation. The home alone talks to its robots: it forwards a dispatch only
from a trusted cloud, for a robot that cloud holds.

Shadows end when their robots report done, when the origin cancels or
releases them, or when reconciliation finds the origin's request over (a
cloud that was down asks each origin, once it is back, which of its robots
are still wanted).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable, Iterable
from typing import Protocol

from robocloud.domain import is_final
from robocloud.errors import Conflict, RoboCloudError, Unavailable
from robocloud.federation.messages import (
    CloudInfo,
    Dispatch,
    Done,
    FleetReply,
    IdleQuery,
    IdleReply,
    Release,
    RequestStatus,
    Reservation,
    ReserveReply,
    StatusQuery,
)
from robocloud.federation.overlay import ZenohOverlay
from robocloud.fleet.link import RobotLink
from robocloud.fleet.messages import Ack, State
from robocloud.storage import RequestRecord, RequestStore

log = logging.getLogger(__name__)

SHADOW_PREFIX = "cloud:"


class OriginStatus(Protocol):
    """The origin side: what this cloud says of its own requests."""

    def coalition_robots(self, request_id: str) -> list[str]: ...


def is_shadow(record: RequestRecord) -> bool:
    return record.application.startswith(SHADOW_PREFIX)


def origin_request(record: RequestRecord) -> str:
    """The origin's id of the request a shadow stands for."""
    return str(record.task.get("request_id", ""))


class Home:
    def __init__(
        self,
        cloud: str,
        store: RequestStore,
        link: RobotLink,
        trusted: Iterable[str] | None = None,
        api: str | None = None,
    ) -> None:
        self.cloud = cloud
        self.store = store
        self.link = link
        self.trusted = set(trusted) if trusted else None  # None: every cloud
        self.api = api
        self.origin: OriginStatus | None = None
        self.overlay: ZenohOverlay | None = None
        link.on_state(self._on_state)

    # -- HomeDesk -------------------------------------------------------------

    def info(self) -> CloudInfo:
        robots = self.link.robots()
        held = self.store.reservations()
        idle = sum(r.status == "idle" and r.id not in held for r in robots)
        offline = sum(r.status == "offline" for r in robots)
        return CloudInfo(
            cloud=self.cloud, robots=len(robots), idle=idle, offline=offline, api=self.api
        )

    def idle_robots(self, query: IdleQuery) -> IdleReply:
        if not self._trusts(query.origin):
            return IdleReply(cloud=self.cloud, robots=[])
        held = self.store.reservations()
        wanted = set(query.capabilities)
        robots = [
            r
            for r in self.link.robots()
            if r.status == "idle"
            and r.id not in held
            and r.battery >= query.min_battery
            and (not wanted or wanted & set(r.capabilities))
        ]
        return IdleReply(cloud=self.cloud, robots=robots)

    def fleet(self) -> FleetReply:
        held = self.store.reservations()
        states = self.link.states()
        out = []
        for robot in self.link.robots():
            state = states.get(robot.id)
            status = "reserved" if robot.status == "idle" and robot.id in held else robot.status
            out.append(
                {
                    **robot.model_dump(mode="json"),
                    "status": status,
                    "kind": state.kind if state else None,
                    "request": None,
                    "progress": state.task.model_dump(mode="json")
                    if state and state.task
                    else None,
                }
            )
        return FleetReply(cloud=self.cloud, robots=out)

    def reserve(self, reservation: Reservation) -> ReserveReply:
        refusal = self._check(reservation.origin, reservation.robots)
        if refusal:
            return ReserveReply(taken=list(reservation.robots), error=refusal)
        shadow = self._shadow(reservation.origin, reservation.request_id)
        try:
            taken = self.store.reserve(shadow.id, reservation.robots, reservation.lease_seconds)
        except Conflict as error:
            return ReserveReply(taken=list(reservation.robots), error=error.message)
        return ReserveReply(taken=taken)

    def confirm(self, reservation: Reservation) -> ReserveReply:
        refusal = self._check(reservation.origin, reservation.robots)
        if refusal:
            return ReserveReply(taken=list(reservation.robots), error=refusal)
        shadow = self._shadow(reservation.origin, reservation.request_id)
        try:
            taken = self.store.confirm(shadow.id, reservation.robots)
            if not taken and shadow.state == "selecting":
                self.store.transition(
                    shadow.id,
                    "dispatched",
                    None,
                    f"robots {', '.join(reservation.robots)} for {reservation.origin}",
                )
        except Conflict as error:
            return ReserveReply(taken=list(reservation.robots), error=error.message)
        return ReserveReply(taken=taken)

    def release(self, release: Release) -> Done:
        if not self._trusts(release.origin):
            return Done(ok=False, error=f"{self.cloud} does not trust {release.origin}.")
        shadow = self._find(release.origin, release.request_id)
        if shadow is not None:
            self.store.release(shadow.id, release.robots)
            self._end_if_empty(shadow.id, "canceled", release.why or "released by the origin")
        return Done()

    def dispatch(self, dispatch: Dispatch) -> Ack:
        command = dispatch.command
        refusal = self._check(dispatch.origin, [dispatch.robot])
        if refusal:
            return Ack.refuse(dispatch.robot, command.request_id, refusal)
        shadow = self._find(dispatch.origin, command.request_id)
        held = self.store.reservations(shadow.id) if shadow is not None else {}
        if dispatch.robot not in held:
            return Ack.refuse(
                dispatch.robot,
                command.request_id,
                f"robot {dispatch.robot} is not reserved for request "
                f"{command.request_id} of {dispatch.origin}.",
            )
        return self.link.assign(dispatch.robot, command)

    def cancel(self, release: Release) -> Done:
        if not self._trusts(release.origin):
            return Done(ok=False, error=f"{self.cloud} does not trust {release.origin}.")
        shadow = self._find(release.origin, release.request_id)
        if shadow is None:
            return Done()
        robots = release.robots or list(self.store.reservations(shadow.id))
        for robot in robots:
            self.link.cancel(robot, release.request_id)
        self.store.release(shadow.id, robots)
        self._end_if_empty(shadow.id, "canceled", release.why or "canceled by the origin")
        return Done()

    def status(self, query: StatusQuery) -> RequestStatus:
        record = self.store.get(query.request_id)
        if record is None or is_shadow(record):
            return RequestStatus(request_id=query.request_id, known=False)
        robots = self.origin.coalition_robots(query.request_id) if self.origin else []
        return RequestStatus(
            request_id=query.request_id, known=True, final=is_final(record.state), robots=robots
        )

    # -- shadows ----------------------------------------------------------------

    def _shadow(self, origin: str, request_id: str) -> RequestRecord:
        """The active shadow of the origin's request, made anew when the last one is over.

        A request may borrow robots of this cloud again after an earlier loan
        ended (a replacement), so shadows are numbered: key ``<request>#<n>``.
        """
        found = self._find(origin, request_id)
        if found is not None:
            return found
        generation = len(self._shadows(origin, request_id)) + 1
        record, created = self.store.create_request(
            SHADOW_PREFIX + origin,
            {"origin": origin, "request_id": request_id},
            f"{origin}/{request_id}",
            f"{request_id}#{generation}",
        )
        if created:
            record = self.store.transition(
                record.id, "selecting", None, f"robots asked for by {origin}"
            )
        return record

    def _shadows(self, origin: str, request_id: str) -> list[RequestRecord]:
        records, _ = self.store.list(SHADOW_PREFIX + origin, None, 200, None)
        return [r for r in records if origin_request(r) == request_id]

    def _find(self, origin: str, request_id: str) -> RequestRecord | None:
        """The shadow of the origin's request that is not over, if any."""
        for record in self._shadows(origin, request_id):
            if not is_final(record.state):
                return record
        return None

    def _end_if_empty(self, shadow_id: str, state: str, why: str) -> None:
        if self.store.reservations(shadow_id):
            return
        with contextlib.suppress(Conflict):  # already over
            self.store.transition(shadow_id, state, None, why)

    def _trusts(self, origin: str) -> bool:
        return self.trusted is None or origin in self.trusted or origin == self.cloud

    def _check(self, origin: str, robots: Iterable[str]) -> str | None:
        if not self._trusts(origin):
            return f"{self.cloud} does not trust {origin}."
        known = {r.id for r in self.link.robots()}
        unknown = [r for r in robots if r not in known]
        if unknown:
            return f"{self.cloud} has no robot {', '.join(unknown)}."
        return None

    def _on_state(self, state: State) -> None:
        """A robot working for another cloud finished: give it back to this cloud."""
        task = state.task
        if task is None or task.phase not in ("done", "failed"):
            return
        held = self.store.reservations()
        shadow_id = held.get(state.id)
        if shadow_id is None:
            return
        record = self.store.get(shadow_id)
        if record is None or not is_shadow(record) or origin_request(record) != task.request_id:
            return
        self.store.release(shadow_id, [state.id])
        self._end_if_empty(
            shadow_id,
            "completed" if task.phase == "done" else "failed",
            "its robots finished" if task.phase == "done" else f"robot {state.id} failed",
        )

    def lent_for(self, robot_id: str) -> str | None:
        """The origin's request id this robot is lent to now, None when it is not lent."""
        shadow_id = self.store.reservations().get(robot_id)
        record = self.store.get(shadow_id) if shadow_id is not None else None
        if record is None or not is_shadow(record) or is_final(record.state):
            return None
        return origin_request(record)

    # -- reconciliation --------------------------------------------------------

    def reconcile(self) -> None:
        """Ask each origin which of this cloud's robots it still wants; free the others."""
        if self.overlay is None:
            return
        for record in self.store.active():
            if not is_shadow(record):
                continue
            if record.state != "dispatched":
                # Leases not yet confirmed lapse by themselves.
                self._end_if_empty(record.id, "canceled", "the lease lapsed")
                continue
            origin = record.application.removeprefix(SHADOW_PREFIX)
            request_id = origin_request(record)
            try:
                status = self.overlay.status(
                    origin, StatusQuery(home=self.cloud, request_id=request_id)
                )
            except RoboCloudError:
                continue  # the origin is away; ask again later
            held = list(self.store.reservations(record.id))
            if not status.known or status.final:
                for robot in held:
                    self.link.cancel(robot, request_id)
                self.store.release(record.id, None)
                self._end_if_empty(record.id, "canceled", f"{origin} says the request is over")
                continue
            unwanted = [r for r in held if r not in status.robots]
            if unwanted:
                self.store.release(record.id, unwanted)
                self.store.add_event(record.id, f"{origin} no longer uses {', '.join(unwanted)}")
                self._end_if_empty(record.id, "canceled", f"{origin} no longer uses them")

    async def reconcile_forever(
        self, every: float = 5.0, sleep: Callable[[float], object] = asyncio.sleep
    ) -> None:
        while True:
            try:
                await asyncio.to_thread(self.reconcile)
            except Unavailable as error:
                log.warning("reconciliation waits for the store: %s", error)
            except Exception:
                log.exception("reconciliation failed")
            await asyncio.sleep(every)
