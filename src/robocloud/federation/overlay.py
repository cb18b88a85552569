"""The overlay between IaaS nodes: presence, scatter-gather, commands via home clouds.

::

    Overlay                 the seam the IaaS uses (a Protocol)
    ├── ZenohOverlay        the real one, on the IaaS's Zenoh router session
    └── MemoryOverlay       in memory, for fast tests (robocloud.federation.memory)
    HomeDesk                what a cloud answers about its own robots (federation.home.Home)

The IaaS gives the overlay a ``HomeDesk``: what its own cloud answers when
other clouds ask (its idle robots, loans, dispatch to its robots). A command
reaches the desk with the sender's name taken from the key it came on
(``robocloud.federation.keys``), never from its payload.

A reply counts only when it comes from the Zenoh session that declared the
presence of the cloud asked (``robocloud.federation.presence``), and only
clouds this one trusts are asked or believed (``HomeDesk.trusts``): the
others' replies are dropped, logged and counted.

Zenoh queries are answered on a small thread pool, never on Zenoh's own
threads, because answering may itself send queries (a dispatch asks the robot).

Why one long file: the Zenoh side of every question and command between
clouds, with the checks of who answered (``presence.py`` decides whom to
believe).
"""

from __future__ import annotations

import contextlib
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
from robocloud.federation import keys
from robocloud.federation.messages import (
    MAX_MESSAGE_BYTES,
    CloudInfo,
    Dispatch,
    Done,
    FleetReply,
    IdleQuery,
    IdleRobots,
    LoanQuery,
    LoanReply,
    Release,
    Reservation,
    ReserveReply,
    StatusQuery,
    StatusReply,
    decode_idle_reply,
)
from robocloud.federation.presence import Presence
from robocloud.fleet import keys as robot_keys
from robocloud.fleet.ingest import StateReader
from robocloud.fleet.link import LatestStates, StateListener
from robocloud.fleet.messages import Ack, State
from robocloud.fleet.state_errors import clock_refusal

logger = logging.getLogger(__name__)

M = TypeVar("M", bound=pydantic.BaseModel)


class Unreachable(RoboCloudError):
    """Another cloud did not answer in time (or its router refused to pass the query)."""


class HomeDesk(Protocol):
    """What a cloud answers about its own robots when other clouds ask.

    Questions come from anyone; commands come with ``origin``, the sender
    named by the key they came on.
    """

    def trusts(self, cloud: str) -> bool:
        """Whether this cloud lends to, and borrows from, ``cloud`` (itself included)."""
        ...

    def info(self) -> CloudInfo: ...
    def idle_robots(self, query: IdleQuery) -> bytes:
        """The ``IdleReply``'s JSON (written by the home: it is on every selection's path)."""
        ...

    def fleet(self) -> FleetReply: ...
    def status(self, query: StatusQuery) -> StatusReply: ...
    def reserve(self, origin: str, reservation: Reservation) -> ReserveReply: ...
    def confirm(self, origin: str, reservation: Reservation) -> ReserveReply: ...
    def release(self, origin: str, release: Release) -> Done: ...
    def dispatch(self, origin: str, dispatch: Dispatch) -> Ack: ...
    def cancel(self, origin: str, release: Release) -> Done: ...
    def loans(self, origin: str, query: LoanQuery) -> LoanReply: ...


@dataclass
class Gathered:
    """The answers of a scatter-gather query: by cloud, and who did not answer."""

    replies: dict[str, IdleRobots] = field(default_factory=dict)
    missing: list[str] = field(default_factory=list)
    elapsed_ms: float = 0.0


class Overlay(Protocol):
    """This cloud's presence on the overlay, and its calls to the other clouds.

    Calls to one cloud raise ``Unreachable`` when it does not answer (except
    ``dispatch``, which answers a refused ``Ack``).
    """

    @property
    def cloud(self) -> str: ...

    def clouds(self) -> list[str]:
        """The live clouds (this one included)."""
        ...

    def infos(self) -> list[CloudInfo]:
        """Every live cloud's info (robot counts), this one's included."""
        ...

    def gather_idle(self, query: IdleQuery, timeout: float | None = None) -> Gathered:
        """The idle robots of every other live cloud that answers within ``timeout``."""
        ...

    def fleets(self) -> list[FleetReply]: ...
    def reserve(self, home: str, reservation: Reservation) -> ReserveReply: ...
    def confirm(self, home: str, reservation: Reservation) -> ReserveReply: ...
    def release(self, home: str, release: Release) -> Done: ...
    def dispatch(self, home: str, dispatch: Dispatch) -> Ack: ...
    def cancel(self, home: str, release: Release) -> Done: ...
    def loans(self, home: str, query: LoanQuery) -> LoanReply: ...
    def status(self, origin: str, query: StatusQuery) -> StatusReply: ...

    def watch(self, cloud: str, robot_id: str) -> None:
        """Follow a remote robot's state (for the requests it works on)."""
        ...

    def unwatch(self, cloud: str, robot_id: str) -> None: ...
    def ages(self) -> dict[str, float]: ...
    def states(self) -> dict[str, State]: ...
    def on_state(self, listener: StateListener) -> Callable[[], None]: ...
    def close(self) -> None: ...


Handler = Callable[[str, bytes], pydantic.BaseModel | bytes]


def desk_handlers(desk: HomeDesk) -> dict[str, Handler]:
    """How each key name is answered: ``(origin, payload) -> reply`` (origin unused by questions).

    A reply is a message, or its JSON when the desk writes it itself (``idle``).

    Shared by the Zenoh and the in-memory overlays, so both parse and answer alike.
    """
    return {
        "info": lambda _, __: desk.info(),
        "idle": lambda _, p: desk.idle_robots(IdleQuery.model_validate_json(p)),
        "fleet": lambda _, __: desk.fleet(),
        "status": lambda _, p: desk.status(StatusQuery.model_validate_json(p)),
        "reserve": lambda o, p: desk.reserve(o, Reservation.model_validate_json(p)),
        "confirm": lambda o, p: desk.confirm(o, Reservation.model_validate_json(p)),
        "release": lambda o, p: desk.release(o, Release.model_validate_json(p)),
        "dispatch": lambda o, p: desk.dispatch(o, Dispatch.model_validate_json(p)),
        "cancel": lambda o, p: desk.cancel(o, Release.model_validate_json(p)),
        "loans": lambda o, p: desk.loans(o, LoanQuery.model_validate_json(p)),
    }


def answer(handler: Handler, origin: str, payload: bytes) -> bytes:
    """The reply's JSON, or ``RoboCloudError`` with the sentence for the asker."""
    if len(payload) > MAX_MESSAGE_BYTES:
        raise RoboCloudError(f"the message is {len(payload)} bytes; at most {MAX_MESSAGE_BYTES}.")
    try:
        reply = handler(origin, payload)
        return reply if isinstance(reply, bytes) else reply.model_dump_json().encode()
    except pydantic.ValidationError as error:
        raise RoboCloudError(f"invalid message: {error.errors()[0]['msg']}") from error


class HomeCommands:
    """The commands to one home cloud, each a ``_command`` by its name: the same
    in every overlay (``ZenohOverlay``, ``robocloud.federation.memory.MemoryOverlay``),
    which says how a command travels."""

    def _command(self, home: str, name: str, message: pydantic.BaseModel, model: type[M]) -> M:
        raise NotImplementedError

    def reserve(self, home: str, reservation: Reservation) -> ReserveReply:
        return self._command(home, "reserve", reservation, ReserveReply)

    def confirm(self, home: str, reservation: Reservation) -> ReserveReply:
        return self._command(home, "confirm", reservation, ReserveReply)

    def release(self, home: str, release: Release) -> Done:
        return self._command(home, "release", release, Done)

    def dispatch(self, home: str, dispatch: Dispatch) -> Ack:
        try:
            return self._command(home, "dispatch", dispatch, Ack)
        except Unreachable as error:
            return Ack.refuse(dispatch.robot, dispatch.command.request_id, error.message)

    def cancel(self, home: str, release: Release) -> Done:
        return self._command(home, "cancel", release, Done)

    def loans(self, home: str, query: LoanQuery) -> LoanReply:
        return self._command(home, "loans", query, LoanReply)


class ZenohOverlay(HomeCommands):
    """The overlay on a Zenoh session (the IaaS's router session)."""

    def __init__(
        self,
        session: zenoh.Session,
        cloud: str,
        desk: HomeDesk,
        timeout: float = 1.0,
        offline_after: float = 5.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._cloud = robot_keys.check_chunk(cloud, "cloud")
        self._session = session
        self._timeout = timeout
        # Commands may wait on robots (a dispatch waits for the robot's ack, up
        # to the ack timeout); questions wait on nothing. Each has its own
        # threads, so commands to robots that do not answer never hold up a
        # question (found with one cloud's simulator frozen: the others' commands
        # to its robots filled the threads, and selections elsewhere left the
        # cloud out for not answering within 500 ms).
        self._pool = ThreadPoolExecutor(8, thread_name_prefix=f"overlay-{cloud}")
        self._asking = ThreadPoolExecutor(4, thread_name_prefix=f"overlay-{cloud}-questions")
        self._subscribing = ThreadPoolExecutor(1, thread_name_prefix=f"overlay-{cloud}-follow")
        self._watched = LatestStates("*", offline_after, clock)
        self._subscribers: dict[str, Any] = {}
        # Robots behind a fleet gateway send no state on their own key: while
        # any robot of a cloud is watched, that cloud's batches are read too,
        # keeping the states of the watched robots only.
        self._watched_ids: dict[str, set[str]] = {}  # cloud -> robot ids
        self._batch_subscribers: dict[str, Any] = {}  # cloud -> subscriber
        self._reader = StateReader()
        self._lock = threading.Lock()
        handlers = desk_handlers(desk)
        self._desk = desk
        self._zid = str(session.zid())
        self.presence = Presence(cloud, self._zid, desk.trusts)
        self._queryables = [
            session.declare_queryable(
                keys.question(cloud, name)
                if name in keys.QUESTIONS
                else keys.command(cloud, "*", name),
                self._handler(
                    handlers[name], self._asking if name in keys.QUESTIONS else self._pool, name
                ),
            )
            for name in (*keys.QUESTIONS, *keys.COMMANDS)
        ]
        # The live clouds, kept by their tokens' comings and goings: a selection
        # asks which clouds to wait for, and a query per selection cost more
        # than the selection (the liveliness get waits for its timeout).
        self._presence = session.liveliness().declare_subscriber(
            keys.all_cloud_tokens(), self._on_presence, history=True
        )
        # Declared last: a cloud that sees the token can query every key above.
        self._token = session.liveliness().declare_token(keys.cloud_token(cloud, self._zid))

    @property
    def cloud(self) -> str:
        return self._cloud

    # -- presence ------------------------------------------------------------

    def clouds(self) -> list[str]:
        # A copy replaced whole, read without a lock: the event loop asks it.
        return self.presence.clouds()

    def _on_presence(self, sample: zenoh.Sample) -> None:
        owner = keys.token_owner(str(sample.key_expr))
        if owner is None:
            return
        if sample.kind == zenoh.SampleKind.PUT:
            self.presence.came(*owner)
        else:
            self.presence.went(*owner)

    def infos(self) -> list[CloudInfo]:
        out = [self._desk.info()]
        for replier, reply in self._scatter("info", None):
            try:
                info = CloudInfo.model_validate_json(reply)
            except pydantic.ValidationError:
                continue
            if info.cloud != self.cloud and self.presence.speaks_for(info.cloud, replier, "info"):
                out.append(info)
        return sorted(out, key=lambda i: i.cloud)

    # -- scatter-gather ------------------------------------------------------

    def gather_idle(self, query: IdleQuery, timeout: float | None = None) -> Gathered:
        started = time.perf_counter()
        expected = set(self.clouds()) - {self.cloud}
        gathered = Gathered()
        if not expected:
            return gathered  # alone on the overlay: nobody to ask
        for replier, payload in self._scatter("idle", query, timeout):
            try:
                reply = decode_idle_reply(payload)
            except ValueError as error:
                logger.warning("ignoring %s", error)
                continue
            if reply.cloud != self.cloud and self.presence.speaks_for(reply.cloud, replier, "idle"):
                gathered.replies[reply.cloud] = reply
        gathered.missing = sorted(expected - set(gathered.replies))
        gathered.elapsed_ms = (time.perf_counter() - started) * 1000
        return gathered

    def fleets(self) -> list[FleetReply]:
        out = []
        for replier, payload in self._scatter("fleet", None):
            try:
                reply = FleetReply.model_validate_json(payload)
            except pydantic.ValidationError:
                continue
            if reply.cloud != self.cloud and self.presence.speaks_for(
                reply.cloud, replier, "fleet"
            ):
                out.append(reply)
        return out

    # -- calls to one cloud -----------------------------------------------------

    def status(self, origin: str, query: StatusQuery) -> StatusReply:
        return self._call(origin, keys.question(origin, "status"), "status", query, StatusReply)

    # -- robots of other clouds ---------------------------------------------------

    def watch(self, cloud: str, robot_id: str) -> None:
        """Follow a remote robot's state, from a moment after this call.

        Declaring a subscriber takes most of a millisecond, and the service
        calls this on its event loop as it dispatches: the subscriptions are
        declared and undeclared on a thread of their own, in the order asked.
        """
        self._later(self._watch, cloud, robot_id)

    def unwatch(self, cloud: str, robot_id: str) -> None:
        self._later(self._unwatch, cloud, robot_id)

    def _later(self, work: Callable[[str, str], None], cloud: str, robot_id: str) -> None:
        with contextlib.suppress(RuntimeError):  # closed: nothing is followed any more
            self._subscribing.submit(self._logged, work, cloud, robot_id)

    @staticmethod
    def _logged(work: Callable[[str, str], None], cloud: str, robot_id: str) -> None:
        try:
            work(cloud, robot_id)
        except Exception:
            logger.exception("following %s of %s failed", robot_id, cloud)

    def _watch(self, cloud: str, robot_id: str) -> None:
        # Only this thread changes the subscribers (``_later``): they are declared
        # outside the lock, which the state callbacks take.
        key = robot_keys.state_key(cloud, robot_id)
        with self._lock:
            if key in self._subscribers:
                return
            batches_wanted = cloud not in self._batch_subscribers
        subscriber = self._session.declare_subscriber(key, self._on_sample)
        batches = (
            self._session.declare_subscriber(
                robot_keys.all_batches(cloud), lambda sample: self._on_batch(cloud, sample)
            )
            if batches_wanted
            else None
        )
        with self._lock:
            self._subscribers[key] = subscriber
            self._watched_ids.setdefault(cloud, set()).add(robot_id)
            if batches is not None:
                self._batch_subscribers[cloud] = batches

    def _unwatch(self, cloud: str, robot_id: str) -> None:
        key = robot_keys.state_key(cloud, robot_id)
        batches = None
        with self._lock:
            subscriber = self._subscribers.pop(key, None)
            ids = self._watched_ids.get(cloud)
            if ids is not None:
                ids.discard(robot_id)
                if not ids:
                    del self._watched_ids[cloud]
                    batches = self._batch_subscribers.pop(cloud, None)
        if subscriber is not None:
            subscriber.undeclare()
        if batches is not None:
            batches.undeclare()

    def ages(self) -> dict[str, float]:
        return self._watched.ages()

    def states(self) -> dict[str, State]:
        return self._watched.states()

    def on_state(self, listener: StateListener) -> Callable[[], None]:
        return self._watched.add_listener(listener)

    def close(self) -> None:
        self._subscribing.shutdown(wait=True, cancel_futures=True)
        self._token.undeclare()  # type: ignore[no-untyped-call]
        self._presence.undeclare()  # type: ignore[no-untyped-call]
        for queryable in self._queryables:
            queryable.undeclare()  # type: ignore[no-untyped-call]
        with self._lock:
            subscribers, self._subscribers = list(self._subscribers.values()), {}
            subscribers += self._batch_subscribers.values()
            self._batch_subscribers, self._watched_ids = {}, {}
        for subscriber in subscribers:
            subscriber.undeclare()
        self._pool.shutdown(wait=False, cancel_futures=True)
        self._asking.shutdown(wait=False, cancel_futures=True)

    # -- internals ------------------------------------------------------------

    def _handler(
        self, handler: Handler, threads: ThreadPoolExecutor, name: str
    ) -> Callable[[zenoh.Query], None]:
        # A question asked of every cloud (robocloud/*/idle) is answered on this
        # cloud's own key: the routers let a cloud reply on its own keys only.
        own = keys.question(self.cloud, name) if name in keys.QUESTIONS else None

        def on_query(query: zenoh.Query) -> None:
            # Keep Zenoh's thread free: the answer may send queries itself.
            threads.submit(self._answer, query, handler, own)

        return on_query

    def _answer(self, query: zenoh.Query, handler: Handler, own: str | None) -> None:
        with query:
            key = str(query.key_expr)
            # A command's sender is the key's: the router let only that cloud send on it.
            origin = keys.sender_of(key) or ""
            payload = query.payload.to_bytes() if query.payload is not None else b""
            try:
                reply = answer(handler, origin, payload)
            except RoboCloudError as error:
                query.reply_err(error.message)
                return
            except Exception:
                logger.exception("answering %s failed", key)
                query.reply_err("internal error")
                return
            query.reply(own or query.key_expr, reply, encoding=zenoh.Encoding.APPLICATION_JSON)

    def _scatter(
        self, name: str, message: pydantic.BaseModel | None, timeout: float | None = None
    ) -> list[tuple[str | None, bytes]]:
        """The ok replies of every cloud's ``name`` queryable: (the replier's session, payload)."""
        replies = self._session.get(
            keys.question("*", name),
            payload=message.model_dump_json() if message is not None else None,
            target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=self._timeout if timeout is None else timeout,
            # Not this cloud's own desk: its answer is known, and the query
            # would wait for it on this process's own threads.
            allowed_destination=zenoh.Locality.REMOTE,
        )
        return [(_replier(r), r.ok.payload.to_bytes()) for r in replies if r.ok is not None]

    def _command(self, home: str, name: str, message: pydantic.BaseModel, model: type[M]) -> M:
        return self._call(home, keys.command(home, self.cloud, name), name, message, model)

    def _call(
        self, cloud: str, key: str, name: str, message: pydantic.BaseModel, model: type[M]
    ) -> M:
        """The reply of ``cloud``'s own session; other sessions' replies are dropped.

        Every queryable on the key is asked (``QueryTarget.ALL``): with the
        default, Zenoh may ask only the nearest, which a forger next to this
        cloud's router would be.
        """
        if self.presence.owner(cloud) is None:
            raise Unreachable(f"{cloud} is not a cloud {self.cloud} trusts on the overlay.")
        replies = self._session.get(
            key,
            payload=message.model_dump_json(),
            encoding=zenoh.Encoding.APPLICATION_JSON,
            target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=self._timeout,
        )
        dropped = 0
        timed_out = ""
        for reply in replies:
            replier = _replier(reply)
            if replier is None and reply.err is not None:
                timed_out = reply.err.payload.to_string()  # Zenoh's own "Timeout"
                break
            if not self.presence.speaks_for(cloud, replier, name):
                dropped += 1
                continue
            if reply.ok is None:
                detail = reply.err.payload.to_string() if reply.err is not None else "?"
                raise Unreachable(f"{cloud} did not answer the {name}: {detail}.")
            try:
                return model.model_validate_json(reply.ok.payload.to_bytes())
            except pydantic.ValidationError as error:
                raise Unreachable(f"{cloud} answered the {name} with an invalid reply.") from error
        if dropped:
            raise Unreachable(
                f"{cloud} did not answer the {name}; {dropped} replies from other sessions "
                "were dropped."
            )
        if timed_out:
            raise Unreachable(f"{cloud} did not answer the {name}: {timed_out}.")
        raise Unreachable(f"{cloud} is not reachable on the overlay.")

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        try:
            state = State.model_validate_json(sample.payload.to_bytes())
        except pydantic.ValidationError:
            return
        # A state counts only on its own robot's key (a state for a-1 sent on
        # b-2's key would otherwise pass for a-1's).
        if robot_keys.robot_of(str(sample.key_expr)) == state.id and not clock_refusal(
            state, time.time()
        ):
            self._watched.accept(state)

    def _on_batch(self, cloud: str, sample: zenoh.Sample) -> None:
        """A gateway's batch of ``cloud``: the states of the robots watched there."""
        if sample.kind != zenoh.SampleKind.PUT:
            return
        with self._lock:
            wanted = set(self._watched_ids.get(cloud, ()))
        if not wanted:
            return
        states, _ = self._reader.read_batch(sample.payload.to_bytes(), only=wanted)
        now = time.time()
        self._watched.accept_many(
            s for s in states if s.cloud == cloud and not clock_refusal(s, now)
        )


def _replier(reply: zenoh.Reply) -> str | None:
    """The Zenoh session id of whoever sent ``reply`` (as Zenoh reports it)."""
    replier = reply.replier_id
    return None if replier is None else str(replier.zid)
