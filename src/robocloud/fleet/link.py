"""The robot link: the I/O seam between an IaaS and the robots of its cloud.

``RobotLink`` is what the IaaS uses; ``ZenohRobotLink`` speaks the messages
of ``robocloud.fleet.messages`` over a Zenoh session, and
``robocloud.fleet.memory.MemoryRobotLink`` is the in-memory one for tests.

Zenoh calls back on its own threads: ``on_state`` listeners run there, and
``assign`` and ``cancel`` block until the robot answers or the timeout
passes, so an asyncio caller uses ``asyncio.to_thread`` for them and hands
states to its loop with ``loop.call_soon_threadsafe``.

Why one file of about 500 lines: the two links (the interface and Zenoh's)
share the ordering, forgetting and bounding rules of one robot's states,
written once here; the columns and the refusals are in their own files.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Protocol

import pydantic
import zenoh

from robocloud.domain import Robot
from robocloud.errors import Unavailable
from robocloud.fleet import keys
from robocloud.fleet.columns import StateColumns
from robocloud.fleet.ingest import Refusal, StateReader
from robocloud.fleet.messages import ARRIVAL_SLACK, Ack, Assign, Cancel, Start, State
from robocloud.fleet.state_errors import (
    MAX_BATCH_BYTES,
    MAX_BATCH_STATES,
    MAX_CLOCK_SKEW,
    MAX_STATE_BYTES,
    StateErrors,
    clock_refusal,
)
from robocloud.selection.columns import FleetColumns

logger = logging.getLogger(__name__)

StateListener = Callable[[State], None]
FORGET_AFTER = 600.0  # seconds of silence after which a robot is forgotten
MAX_FLEET = 100_000  # robots one link follows at most


class RobotLink(Protocol):
    """The live robots of one cloud, and the commands they take."""

    @property
    def cloud(self) -> str: ...

    def robots(self) -> list[Robot]:
        """Every robot heard from, as docs/model.md robots; ``offline`` when silent too long."""
        ...

    def states(self) -> dict[str, State]:
        """The latest state of each robot heard from, by id."""
        ...

    def columns(self) -> FleetColumns:
        """The robots of ``robots()`` as columns (what a selection filters)."""
        ...

    def state(self, robot_id: str) -> State | None:
        """The latest state of one robot, None if it is not heard from."""
        ...

    def ages(self) -> dict[str, float]:
        """Seconds since each robot last said something new (its sent_at went forward), by id."""
        ...

    def refused(self) -> dict[str, str]:
        """Why the last state of a robot was refused, by id, until one of its states is accepted."""
        ...

    def state_refusals(self) -> dict[str, int]:
        """States refused so far, by the field that was wrong; ``overtaken``: states held
        for a while that had claimed a ``sent_at`` ahead and a greater ``seq`` (forged, or a
        robot that restarted with its clock ahead)."""
        ...

    def assign(self, robot_id: str, command: Assign) -> Ack:
        """Send a task to a robot; its acknowledgement, or not ok when it does not answer."""
        ...

    def cancel(self, robot_id: str, request_id: str) -> Ack:
        """Stop a robot working on ``request_id``."""
        ...

    def start(self, robot_id: str, request_id: str) -> Ack:
        """Protocol 1.2: let a robot held at its task's place start working on ``request_id``."""
        ...

    def on_state(self, listener: StateListener) -> Callable[[], None]:
        """Call ``listener`` with every new state; returns a function that stops it."""
        ...

    def close(self) -> None: ...


class LatestStates:
    """The latest states, their receive times and the listeners, behind one lock.

    Shared by the Zenoh and the in-memory links so both judge staleness,
    ordering and silence the same way.
    """

    def __init__(
        self,
        cloud: str,
        offline_after: float,
        clock: Callable[[], float],
        forget_after: float = FORGET_AFTER,
        max_fleet: int = MAX_FLEET,
        wall: Callable[[], float] = time.time,
    ) -> None:
        self.cloud = cloud
        self.offline_after = offline_after
        self.clock = clock
        self.wall = wall  # this IaaS's unix clock, against the states' sent_at
        self.forget_after = forget_after
        self.max_fleet = max_fleet
        self._lock = threading.Lock()
        self._pruned_at = clock()
        self._refused = 0  # states of new robots refused since the fleet was full
        self._overtaken = 0  # held states overtaken because they claimed a time ahead
        self._unavailable_said = -1e9
        self._states: dict[str, State] = {}
        self._received: dict[str, float] = {}
        # When each robot last said something new: a state whose sent_at went
        # forward. A gateway repeats a silent robot's last state (a new seq, the
        # same sent_at): the robot's listed age grows, though its states come.
        self._said: dict[str, float] = {}
        self._listeners: list[StateListener] = []
        # The Robot of each held state, made when first asked for and kept
        # while the robot's states say the same (see ``robots``).
        self._robots: dict[str, Robot] = {}
        self._order: list[str] | None = None  # the ids, sorted; None when to sort again
        # The last list of robots() and until when it holds; None when a robot
        # joined, changed, came back or was forgotten since.
        self._listed: list[Robot] | None = None
        self._listed_until = 0.0
        # The same robots as rows of arrays, for selections (``columns``).
        self._columns = StateColumns()

    def accept(self, state: State) -> bool:
        """Keep ``state`` if it is newer than the one held; tell the listeners.

        Robots silent for ``forget_after`` seconds are forgotten, and a new
        robot is refused while ``max_fleet`` robots are known: whatever ids
        clients publish, memory stays bounded.
        """
        return self.accept_many([state]) == 1

    def accept_many(self, states: Iterable[State]) -> int:
        """``accept`` for several states under one lock (a gateway's batch); how many were kept."""
        now = self.clock()
        wall = self.wall()
        kept: list[State] = []
        with self._lock:
            if now - self._pruned_at > min(10.0, self.forget_after / 10):
                self._forget_silent(now)
            for state in states:
                if self._keep(state, now, wall):
                    kept.append(state)
            if len(self._columns.sets) > 2 * len(self._states) + 1024:
                # Capability sets no robot has any more: start the rows again.
                self._columns = StateColumns.of(self._states, self._received)
            listeners = list(self._listeners) if kept else []
        for listener in listeners:
            for state in kept:
                try:
                    listener(state)
                except Unavailable as error:
                    # A store that is down fails every state for a while: say it
                    # once every few seconds, without a traceback.
                    if now - self._unavailable_said > 5.0:
                        self._unavailable_said = now
                        logger.warning("a robot state listener could not go on: %s", error)
                except Exception:
                    logger.exception("a robot state listener failed")
        return len(kept)

    def _keep(self, state: State, now: float, wall: float) -> bool:
        """Hold ``state`` if it is newer (the caller holds the lock); ``now`` is the
        monotonic clock, ``wall`` this IaaS's unix clock, read once for a batch."""
        held = self._states.get(state.id)
        # An old or repeated message (a reconnected robot may send its last one
        # again) is dropped; a restarted robot's is not (State.is_newer_than).
        # The held state counts as sent no later than it arrived (plus a slack):
        # one forged with a huge seq and a sent_at ahead is overtaken by the
        # robot's own within seconds.
        if held is not None:
            arrived = wall - (now - self._received[state.id])
            if not state.is_newer_than(held, arrived + ARRIVAL_SLACK):
                return False
            if held.sent_at > arrived + ARRIVAL_SLACK and not state.is_newer_than(held):
                self._overtake(state, held, arrived)
        if held is None and len(self._states) >= self.max_fleet:
            self._forget_silent(now)
            if len(self._states) >= self.max_fleet:
                self._refused += 1
                if self._refused == 1 or self._refused % 1000 == 0:
                    logger.warning(
                        "%s already follows %d robots, the most it takes; "
                        "ignoring robot %s (%d refused so far)",
                        self.cloud,
                        self.max_fleet,
                        state.id,
                        self._refused,
                    )
                return False
        changed = held is None or not _same_robot(held, state)
        if held is None:
            self._order = None  # a new robot: the sorted ids are made again
            self._listed = None
        else:
            if changed and state.id in self._robots:
                del self._robots[state.id]  # its Robot is made again when asked for
                self._listed = None
            elif now - self._received[state.id] > self.offline_after:
                self._listed = None  # back from silence: listed online again
        self._states[state.id] = state
        self._received[state.id] = now
        if held is None or state.sent_at > held.sent_at:
            self._said[state.id] = now
        self._columns.put(state, now, changed)
        return True

    def _overtake(self, state: State, held: State, arrived: float) -> None:
        """``held`` claimed a time ahead of its arrival and is overtaken only because of it:
        say so (the caller holds the lock)."""
        self._overtaken += 1
        if self._overtaken <= 20 or self._overtaken % 1000 == 0:
            logger.warning(
                "robot %s's state of seq %d claimed to be sent at %.3f, %.1f s after it "
                "arrived; its state of seq %d, sent at %.3f, takes its place (a forged state, "
                "or the robot restarted with its clock ahead; %d so far)",
                held.id,
                held.seq,
                held.sent_at,
                held.sent_at - arrived,
                state.seq,
                state.sent_at,
                self._overtaken,
            )

    def overtaken(self) -> dict[str, int]:
        """``{"overtaken": n}``: held states overtaken because they claimed a time ahead."""
        with self._lock:
            return {"overtaken": self._overtaken} if self._overtaken else {}

    def _forget_silent(self, now: float) -> None:
        """Drop the robots silent for longer than ``forget_after`` (the caller holds the lock)."""
        self._pruned_at = now
        gone = [rid for rid, at in self._received.items() if now - at > self.forget_after]
        for rid in gone:
            del self._states[rid], self._received[rid], self._said[rid]
            self._robots.pop(rid, None)
        if gone:
            self._columns = StateColumns.of(self._states, self._received)
            self._order = None
            self._listed = None
            self._refused = 0
            logger.info("forgot %d robots silent for over %.0f s", len(gone), self.forget_after)

    def states(self) -> dict[str, State]:
        with self._lock:
            return dict(self._states)

    def state(self, robot_id: str) -> State | None:
        with self._lock:
            return self._states.get(robot_id)

    def count(self) -> int:
        """How many robots are heard from (without building them)."""
        with self._lock:
            return len(self._states)

    def ages(self) -> dict[str, float]:
        now = self.clock()
        with self._lock:
            return {rid: now - at for rid, at in self._said.items()}

    def columns(self) -> FleetColumns:
        """The robots of ``robots()`` as columns, without making a Robot of any."""
        now = self.clock()
        with self._lock:
            return self._columns.snapshot(now - self.offline_after)

    def robots(self) -> list[Robot]:
        """Every robot by id; a Robot is made only for a state that changed what it says.

        A state at 1 Hz mostly repeats the robot (only ``seq`` and
        ``sent_at`` move): its Robot is kept, and so is the whole sorted list
        until a robot joins, changes, falls silent or comes back, or is
        forgotten. A selection over 50,000 idle robots then copies a list
        instead of visiting 50,000 robots.
        """
        now = self.clock()
        with self._lock:
            if self._listed is None or now >= self._listed_until:
                self._listed = self._list(now)
            return list(self._listed)

    def _list(self, now: float) -> list[Robot]:
        """The robots, sorted by id, as of ``now`` (the caller holds the lock).

        Sets ``_listed_until``: when the first robot listed online would fall
        silent if it sent nothing more (a state only moves that later).
        """
        order = self._order
        if order is None:
            order = self._order = sorted(self._states)
        states, received, made = self._states, self._received, self._robots
        stale_before = now - self.offline_after
        oldest_online = now
        robots = []
        for rid in order:
            robot = made.get(rid)
            if robot is None:
                robot = made[rid] = states[rid].to_robot()
            at = received[rid]
            if at < stale_before:
                if robot.status != "offline":
                    robot = robot.model_copy(update={"status": "offline"})
            elif at < oldest_online:
                oldest_online = at
            robots.append(robot)
        self._listed_until = oldest_online + self.offline_after
        return robots

    def add_listener(self, listener: StateListener) -> Callable[[], None]:
        with self._lock:
            self._listeners.append(listener)

        def remove() -> None:
            with self._lock:
                if listener in self._listeners:
                    self._listeners.remove(listener)

        return remove


def _same_robot(a: State, b: State) -> bool:
    """Whether two states of one robot describe the same docs/model.md robot."""
    return (
        a.status == b.status
        and a.battery == b.battery
        and a.position == b.position
        and a.speed == b.speed
        and a.travel_cost_per_m == b.travel_cost_per_m
        and a.cloud == b.cloud
        and (a.capabilities is b.capabilities or a.capabilities == b.capabilities)
    )


class ZenohRobotLink:
    """The robots of ``cloud`` over a Zenoh session (the IaaS's router session).

    A robot silent for more than ``offline_after`` seconds is reported
    ``offline`` by ``robots()``; a command unanswered within
    ``command_timeout`` seconds is acknowledged not ok. A state that does not
    validate, or whose ``sent_at`` is more than ``max_clock_skew`` seconds
    from ``wall`` (this IaaS's clock), is answered on the robot's error key
    (``StateErrors``).
    """

    def __init__(
        self,
        session: zenoh.Session,
        cloud: str,
        offline_after: float = 5.0,
        command_timeout: float = 2.0,
        clock: Callable[[], float] = time.monotonic,
        forget_after: float = FORGET_AFTER,
        max_fleet: int = MAX_FLEET,
        max_clock_skew: float = MAX_CLOCK_SKEW,
        wall: Callable[[], float] = time.time,
        fronts: Mapping[str, Iterable[str]] | None = None,
    ) -> None:
        self._session = session
        # Gateways with a certificate of their own -> the robots each fronts: their
        # batches may hold those robots' states only (the router lets such a gateway
        # put on its own batch key, and cannot read what is in a batch).
        self._fronts = {name: frozenset(ids) for name, ids in (fronts or {}).items()}
        self._skew = max_clock_skew
        self._wall = wall
        self._cloud = keys.check_chunk(cloud, "cloud")
        self._timeout = command_timeout
        self._latest = LatestStates(cloud, offline_after, clock, forget_after, max_fleet, wall)
        self._errors = StateErrors(session, self._cloud)
        self._reader = StateReader()
        self._subscriber = session.declare_subscriber(keys.all_states(cloud), self._on_sample)
        self._batches = session.declare_subscriber(keys.all_batches(cloud), self._on_batch)

    @property
    def cloud(self) -> str:
        return self._cloud

    def robots(self) -> list[Robot]:
        return self._latest.robots()

    def states(self) -> dict[str, State]:
        return self._latest.states()

    def columns(self) -> FleetColumns:
        return self._latest.columns()

    def state(self, robot_id: str) -> State | None:
        return self._latest.state(robot_id)

    def ages(self) -> dict[str, float]:
        return self._latest.ages()

    def refused(self) -> dict[str, str]:
        return self._errors.refused()

    def state_refusals(self) -> dict[str, int]:
        return {**self._errors.counts(), **self._latest.overtaken()}

    def on_state(self, listener: StateListener) -> Callable[[], None]:
        return self._latest.add_listener(listener)

    def assign(self, robot_id: str, command: Assign) -> Ack:
        return self._command(robot_id, command)

    def cancel(self, robot_id: str, request_id: str) -> Ack:
        return self._command(robot_id, Cancel(request_id=request_id))

    def start(self, robot_id: str, request_id: str) -> Ack:
        return self._command(robot_id, Start(request_id=request_id))

    def count(self) -> int:
        """How many robots are heard from."""
        return self._latest.count()

    def close(self) -> None:
        self._subscriber.undeclare()  # type: ignore[no-untyped-call]
        self._batches.undeclare()  # type: ignore[no-untyped-call]

    def __enter__(self) -> ZenohRobotLink:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def _command(self, robot_id: str, command: Assign | Cancel | Start) -> Ack:
        replies = self._session.get(
            keys.cmd_key(self._cloud, robot_id),
            payload=command.model_dump_json(),
            encoding=zenoh.Encoding.APPLICATION_JSON,
            # One robot per key, but should two answer (a robot and a stale
            # simulator of the same cloud) every reply arrives and the first
            # one wins instead of Zenoh merging them.
            target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=self._timeout,
        )
        for reply in replies:
            return self._ack(robot_id, command.request_id, reply)
        return Ack.no_answer(robot_id, command.request_id, self._timeout)

    def _ack(self, robot_id: str, request_id: str, reply: zenoh.Reply) -> Ack:
        sample = reply.ok
        if sample is None:
            error = reply.err
            detail = error.payload.to_string() if error is not None else "no detail"
            if detail == "Timeout":
                # What Zenoh itself replies when the timeout passes with the
                # query still open at the robot.
                return Ack.no_answer(robot_id, request_id, self._timeout)
            return Ack.refuse(robot_id, request_id, f"robot {robot_id} answered an error: {detail}")
        try:
            return Ack.model_validate_json(sample.payload.to_bytes())
        except pydantic.ValidationError:
            return Ack.refuse(
                robot_id, request_id, f"robot {robot_id} answered something that is not an Ack."
            )

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        key = str(sample.key_expr)
        payload = sample.payload.to_bytes()
        if len(payload) > MAX_STATE_BYTES:
            self._errors.too_large(key, len(payload))
            return
        read = self._reader.read(payload)
        if isinstance(read, Refusal):
            self._errors.refuse(key, read.field, read.sentence)
            return
        if read.cloud != self._cloud or read.id != keys.robot_of(key):
            self._errors.mismatch(key, read)
            return
        late = clock_refusal(read, self._wall(), self._skew)
        if late is not None:
            self._errors.refuse(key, "sent_at", late)
            return
        self._latest.accept(read)
        self._errors.accepted([read.id])

    def _on_batch(self, sample: zenoh.Sample) -> None:
        """A gateway's batch: a JSON array of states of its robots (``keys.batch_key``)."""
        if sample.kind != zenoh.SampleKind.PUT:
            return
        key = str(sample.key_expr)
        payload = sample.payload.to_bytes()
        if len(payload) > MAX_BATCH_BYTES:
            self._errors.refuse(
                key,
                "states",
                f"the batch is {len(payload)} bytes; at most {MAX_BATCH_BYTES} are accepted.",
                robot="",
            )
            return
        states, refusals = self._reader.read_batch(payload, MAX_STATE_BYTES)
        if len(states) + len(refusals) > MAX_BATCH_STATES:
            self._errors.refuse(
                key,
                "states",
                f"the batch has {len(states) + len(refusals)} states; "
                f"at most {MAX_BATCH_STATES} are accepted.",
                robot="",
            )
            return
        for refusal in refusals:
            self._errors.in_batch(key, refusal.robot, refusal.field, refusal.sentence)
        mine = []
        now = self._wall()
        gateway = keys.gateway_of(key)
        fronted = self._fronts.get(gateway) if gateway is not None else None
        for state in states:
            late = clock_refusal(state, now, self._skew)
            if late is not None:
                self._errors.in_batch(key, state.id, "sent_at", late)
            elif fronted is not None and state.id not in fronted:
                self._errors.in_batch(
                    key,
                    state.id,
                    "id",
                    f"id: robot {state.id} is not one of the robots gateway {gateway} fronts "
                    "(its IaaS's --gateways); its state was not kept.",
                )
            elif state.cloud != self._cloud:
                self._errors.in_batch(
                    key,
                    state.id,
                    "cloud",
                    f"cloud: the state names cloud {state.cloud} but came on a key of "
                    f"{self._cloud}.",
                )
            else:
                mine.append(state)
        self._latest.accept_many(mine)
        self._errors.accepted([state.id for state in mine])
