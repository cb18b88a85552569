"""The overlay between IaaS nodes over Zenoh: presence, scatter-gather, commands via home clouds.

``Overlay`` is the seam the IaaS uses; ``ZenohOverlay`` is the real one. The
IaaS gives the overlay a ``HomeDesk``: what its own cloud answers when other
clouds ask (its idle robots, reservations, dispatch to its robots).

Queries are answered on a small thread pool, never on Zenoh's own threads,
because answering may itself send queries (a dispatch asks the robot).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar

import pydantic
import zenoh

from robocloud.errors import RoboCloudError
from robocloud.federation.messages import (
    CLOUDS_TOKEN,
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
from robocloud.fleet import keys
from robocloud.fleet.link import LatestStates, StateListener
from robocloud.fleet.messages import Ack, State

logger = logging.getLogger(__name__)

M = TypeVar("M", bound=pydantic.BaseModel)


class Unreachable(RoboCloudError):
    """Another cloud did not answer in time."""


class HomeDesk(Protocol):
    """What a cloud answers about its own robots when other clouds ask."""

    def info(self) -> CloudInfo: ...
    def idle_robots(self, query: IdleQuery) -> IdleReply: ...
    def fleet(self) -> FleetReply: ...
    def reserve(self, reservation: Reservation) -> ReserveReply: ...
    def confirm(self, reservation: Reservation) -> ReserveReply: ...
    def release(self, release: Release) -> Done: ...
    def dispatch(self, dispatch: Dispatch) -> Ack: ...
    def cancel(self, release: Release) -> Done: ...
    def status(self, query: StatusQuery) -> RequestStatus: ...


@dataclass
class Gathered:
    """The answers of a scatter-gather query: by cloud, and who did not answer."""

    replies: dict[str, IdleReply] = field(default_factory=dict)
    missing: list[str] = field(default_factory=list)
    elapsed_ms: float = 0.0


class ZenohOverlay:
    """This cloud's presence on the overlay, and its calls to the other clouds."""

    def __init__(
        self,
        session: zenoh.Session,
        cloud: str,
        desk: HomeDesk,
        timeout: float = 1.0,
        offline_after: float = 5.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.cloud = keys.check_chunk(cloud, "cloud")
        self._session = session
        self._desk = desk
        self._timeout = timeout
        self._pool = ThreadPoolExecutor(8, thread_name_prefix=f"overlay-{cloud}")
        self._watched = LatestStates("*", offline_after, clock)
        self._subscribers: dict[str, Any] = {}
        self._lock = threading.Lock()
        handlers: dict[str, Callable[[bytes], pydantic.BaseModel]] = {
            "info": lambda _: desk.info(),
            "idle": lambda p: desk.idle_robots(IdleQuery.model_validate_json(p)),
            "fleet": lambda _: desk.fleet(),
            "reserve": lambda p: desk.reserve(Reservation.model_validate_json(p)),
            "confirm": lambda p: desk.confirm(Reservation.model_validate_json(p)),
            "release": lambda p: desk.release(Release.model_validate_json(p)),
            "dispatch": lambda p: desk.dispatch(Dispatch.model_validate_json(p)),
            "cancel": lambda p: desk.cancel(Release.model_validate_json(p)),
            "status": lambda p: desk.status(StatusQuery.model_validate_json(p)),
        }
        self._queryables = [
            session.declare_queryable(f"robocloud/{cloud}/{name}", self._handler(handler))
            for name, handler in handlers.items()
        ]
        # Declared last: a cloud that sees the token can query every key above.
        self._token = session.liveliness().declare_token(f"{CLOUDS_TOKEN}/{cloud}")

    # -- presence ------------------------------------------------------------

    def clouds(self) -> list[str]:
        """The live clouds (this one included), by their liveliness tokens."""
        names = set()
        for reply in self._session.liveliness().get(f"{CLOUDS_TOKEN}/*", timeout=self._timeout):
            if reply.ok is not None:
                names.add(str(reply.ok.key_expr).rsplit("/", 1)[-1])
        return sorted(names)

    def infos(self) -> list[CloudInfo]:
        """Every live cloud's info (robot counts), this one's included."""
        out = [self._desk.info()]
        for reply in self._scatter("info", None):
            try:
                info = CloudInfo.model_validate_json(reply)
            except pydantic.ValidationError:
                continue
            if info.cloud != self.cloud:
                out.append(info)
        return sorted(out, key=lambda i: i.cloud)

    # -- scatter-gather ------------------------------------------------------

    def gather_idle(self, query: IdleQuery, timeout: float | None = None) -> Gathered:
        """The idle robots of every other live cloud that answers within ``timeout``."""
        started = time.perf_counter()
        expected = set(self.clouds()) - {self.cloud}
        gathered = Gathered()
        for payload in self._scatter("idle", query, timeout):
            try:
                reply = IdleReply.model_validate_json(payload)
            except pydantic.ValidationError:
                logger.warning("ignoring an invalid idle reply")
                continue
            if reply.cloud != self.cloud:
                gathered.replies[reply.cloud] = reply
        gathered.missing = sorted(expected - set(gathered.replies))
        gathered.elapsed_ms = (time.perf_counter() - started) * 1000
        return gathered

    def fleets(self) -> list[FleetReply]:
        out = []
        for payload in self._scatter("fleet", None):
            try:
                reply = FleetReply.model_validate_json(payload)
            except pydantic.ValidationError:
                continue
            if reply.cloud != self.cloud:
                out.append(reply)
        return out

    # -- calls to one cloud -----------------------------------------------------

    def reserve(self, home: str, reservation: Reservation) -> ReserveReply:
        return self._call(home, "reserve", reservation, ReserveReply)

    def confirm(self, home: str, reservation: Reservation) -> ReserveReply:
        return self._call(home, "confirm", reservation, ReserveReply)

    def release(self, home: str, release: Release) -> Done:
        return self._call(home, "release", release, Done)

    def dispatch(self, home: str, dispatch: Dispatch) -> Ack:
        try:
            return self._call(home, "dispatch", dispatch, Ack)
        except Unreachable as error:
            return Ack.refuse(dispatch.robot, dispatch.command.request_id, error.message)

    def cancel(self, home: str, release: Release) -> Done:
        return self._call(home, "cancel", release, Done)

    def status(self, origin: str, query: StatusQuery) -> RequestStatus:
        return self._call(origin, "status", query, RequestStatus)

    # -- robots of other clouds ---------------------------------------------------

    def watch(self, cloud: str, robot_id: str) -> None:
        """Follow a remote robot's state (for the requests it works on)."""
        key = keys.state_key(cloud, robot_id)
        with self._lock:
            if key in self._subscribers:
                return
            self._subscribers[key] = self._session.declare_subscriber(key, self._on_sample)

    def unwatch(self, cloud: str, robot_id: str) -> None:
        key = keys.state_key(cloud, robot_id)
        with self._lock:
            subscriber = self._subscribers.pop(key, None)
        if subscriber is not None:
            subscriber.undeclare()

    def ages(self) -> dict[str, float]:
        return self._watched.ages()

    def states(self) -> dict[str, State]:
        return self._watched.states()

    def on_state(self, listener: StateListener) -> Callable[[], None]:
        return self._watched.add_listener(listener)

    def close(self) -> None:
        self._token.undeclare()  # type: ignore[no-untyped-call]
        for queryable in self._queryables:
            queryable.undeclare()  # type: ignore[no-untyped-call]
        with self._lock:
            subscribers, self._subscribers = list(self._subscribers.values()), {}
        for subscriber in subscribers:
            subscriber.undeclare()
        self._pool.shutdown(wait=False, cancel_futures=True)

    # -- internals ------------------------------------------------------------

    def _handler(
        self, answer: Callable[[bytes], pydantic.BaseModel]
    ) -> Callable[[zenoh.Query], None]:
        def on_query(query: zenoh.Query) -> None:
            # Keep Zenoh's thread free: the answer may send queries itself.
            self._pool.submit(self._answer, query, answer)

        return on_query

    def _answer(self, query: zenoh.Query, answer: Callable[[bytes], pydantic.BaseModel]) -> None:
        with query:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            try:
                reply = answer(payload)
            except pydantic.ValidationError as error:
                query.reply_err(f"invalid message: {error.errors()[0]['msg']}")
                return
            except RoboCloudError as error:
                query.reply_err(error.message)
                return
            except Exception:
                logger.exception("answering %s failed", query.key_expr)
                query.reply_err("internal error")
                return
            query.reply(
                query.key_expr, reply.model_dump_json(), encoding=zenoh.Encoding.APPLICATION_JSON
            )

    def _scatter(
        self, name: str, message: pydantic.BaseModel | None, timeout: float | None = None
    ) -> list[bytes]:
        replies = self._session.get(
            f"robocloud/*/{name}",
            payload=message.model_dump_json() if message is not None else None,
            target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=self._timeout if timeout is None else timeout,
        )
        return [r.ok.payload.to_bytes() for r in replies if r.ok is not None]

    def _call(self, cloud: str, name: str, message: pydantic.BaseModel, model: type[M]) -> M:
        replies = self._session.get(
            f"robocloud/{cloud}/{name}",
            payload=message.model_dump_json(),
            encoding=zenoh.Encoding.APPLICATION_JSON,
            timeout=self._timeout,
        )
        for reply in replies:
            if reply.ok is None:
                detail = reply.err.payload.to_string() if reply.err is not None else "?"
                raise Unreachable(f"{cloud} did not answer the {name}: {detail}.")
            return model.model_validate_json(reply.ok.payload.to_bytes())
        raise Unreachable(f"{cloud} is not reachable on the overlay.")

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        try:
            state = State.model_validate_json(sample.payload.to_bytes())
        except pydantic.ValidationError:
            return
        self._watched.accept(state)
