"""The fleet simulator: many simulated robots of one cloud behind one Zenoh client session.

Each robot publishes its State on its own key and answers Commands on its
own key (one queryable on ``robocloud/<cloud>/robots/*/cmd`` dispatches by
key), exactly as a real robot would; the IaaS cannot tell them apart.

With ``gateway`` set, the simulator is a fleet gateway instead (docs/protocol.md,
"Fleet gateways"): it declares no key per robot at all and publishes the
states of its robots in batches (JSON arrays of at most ``batch_size``
states) on ``robocloud/<cloud>/fleets/<gateway>/states``. Declaring a
publisher per robot costs the router more than linearly: 20,000 robots took
35 s to join that way and 50,000 none within 120 s, where through a gateway
50,000 join in a few seconds (benchmarks/fleet.py). Commands come the same
way in both modes.

Time: a tick thread runs every ``tick`` wall seconds and advances the
simulation by the elapsed wall time times ``speedup``, so a ten-minute task
takes six seconds at ``speedup=100``. Publishing stays in wall time: every
robot publishes at least once a second, the fleet spread over the second,
plus once for every change of status or phase. Commands only change the
robots; the next tick publishes the change, so all publishing happens on
one thread, in order.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pydantic
import zenoh

from robocloud.domain import Robot
from robocloud.errors import InvalidInput, describe_validation_errors
from robocloud.fleet import keys
from robocloud.fleet.ingest import WireState, encode_batch
from robocloud.fleet.messages import COMMAND, Ack, Assign, Cancel, Start, State
from robocloud.fleet.state_errors import MAX_BATCH_STATES
from robocloud.fleet.zenoh_session import SessionSecurity, open_client
from robocloud.sim.churn import Churn
from robocloud.sim.control import Fault, FaultName
from robocloud.sim.metrics import serve_metrics
from robocloud.sim.robot import SimRobot
from robocloud.sim.roster import cloud_robots

logger = logging.getLogger(__name__)

TICK = 0.1  # wall seconds between simulation steps
# Wall seconds between a robot's periodic states: under one second with the
# tick's jitter on top.
PUBLISH_PERIOD = 0.9
_JSON = zenoh.Encoding.APPLICATION_JSON
BATCH_SIZE = 1000  # states in one batch of a gateway (about 400 KB)


class FleetSimulator:
    """``robots`` (docs/model.md robot dicts, optionally with ``kind``, or Robots) of ``cloud``.

    ``churn`` lets robots start and end background activities on their own
    (``robocloud.sim.churn``); without it a robot changes only by commands
    and faults. Use as a context manager, or ``start()`` and ``stop()``; the
    session stays the caller's.
    """

    def __init__(
        self,
        cloud: str,
        robots: Sequence[Mapping[str, Any] | Robot],
        session: zenoh.Session,
        speedup: float = 1.0,
        seed: int = 0,
        churn: bool = False,
        tick: float = TICK,
        gateway: str | None = None,
        batch_size: int = BATCH_SIZE,
        recharge_below: float | None = None,
    ) -> None:
        keys.check_chunk(cloud, "cloud")
        if gateway is not None:
            keys.check_chunk(gateway, "gateway")
        if not 1 <= batch_size <= MAX_BATCH_STATES:
            raise InvalidInput(
                f"batch_size must be from 1 to {MAX_BATCH_STATES}, not {batch_size}.",
                field="batch_size",
            )
        self.gateway = gateway
        self.batch_size = batch_size
        if not speedup > 0.0:
            raise InvalidInput(f"speedup must be more than 0, not {speedup}.", field="speedup")
        if not tick > 0.0:
            raise InvalidInput(f"tick must be more than 0, not {tick}.", field="tick")
        self.cloud = cloud
        self.speedup = speedup
        self.tick = tick
        self._session = session
        self._robots = [_sim_robot(data, i) for i, data in enumerate(robots)]
        self._by_id: dict[str, SimRobot] = {}
        for robot in self._robots:
            if robot.cloud != cloud:
                raise InvalidInput(
                    f"robot {robot.id} belongs to {robot.cloud}, not {cloud}.", field="cloud"
                )
            keys.check_chunk(robot.id, "robot")
            if robot.id in self._by_id:
                raise InvalidInput(f"robot id {robot.id} is used twice.", field="robots")
            self._by_id[robot.id] = robot
        if recharge_below is not None and not 0.0 < recharge_below <= 100.0:
            raise InvalidInput(
                f"recharge_below must be a percentage above 0 and at most 100, "
                f"not {recharge_below}.",
                field="recharge_below",
            )
        self._churn = Churn(
            np.random.default_rng([seed, 2]), enabled=churn, recharge_below=recharge_below
        )
        for robot in self._robots:
            self._churn.adopt(robot)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._publishers: list[zenoh.Publisher] = []
        self._batches: zenoh.Publisher | None = None
        self._declared: list[zenoh.Queryable[None] | zenoh.LivelinessToken] = []
        self._next_publish = np.zeros(len(self._robots))
        self.ticks = 0
        self.late_ticks = 0
        # For the metrics (robocloud.sim.metrics): plain counters, read at a scrape.
        self.states_published = 0
        self.commands_answered: dict[tuple[str, str], int] = {}

    @property
    def robot_ids(self) -> list[str]:
        return [robot.id for robot in self._robots]

    def status_counts(self) -> dict[str, int]:
        """How many robots are in each status now."""
        counts: dict[str, int] = {}
        with self._lock:
            for robot in self._robots:
                counts[robot.status] = counts.get(robot.status, 0) + 1
        return counts

    # Life cycle -------------------------------------------------------------

    def start(self) -> None:
        """Declare the robots on the session and start the tick thread."""
        if self._thread is not None:
            return
        session = self._session
        # Queryables first, the liveliness token last: whoever sees the token
        # or a state can reach the robots.
        self._declared.append(
            session.declare_queryable(keys.all_cmds(self.cloud), self._on_command)
        )
        self._declared.append(
            session.declare_queryable(keys.sim_control(self.cloud), self._on_control)
        )
        if self.gateway is not None:
            self._batches = session.declare_publisher(
                keys.batch_key(self.cloud, self.gateway), encoding=_JSON
            )
        else:
            self._publishers = [
                session.declare_publisher(keys.state_key(self.cloud, robot.id), encoding=_JSON)
                for robot in self._robots
            ]
        self._declared.append(
            session.liveliness().declare_token(keys.sim_token(self.cloud, os.getpid()))
        )
        # The first states spread over the first period.
        n = len(self._robots)
        self._next_publish = time.monotonic() + PUBLISH_PERIOD * np.arange(n) / max(n, 1)
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name=f"sim-{self.cloud}", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the tick thread and undeclare everything; the session stays open."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        batches = [self._batches] if self._batches is not None else []
        for entity in [*self._declared, *self._publishers, *batches]:
            # A session closed first has undeclared everything already.
            with contextlib.suppress(zenoh.ZError):
                entity.undeclare()  # type: ignore[no-untyped-call]
        self._declared = []
        self._publishers = []
        self._batches = None

    def __enter__(self) -> FleetSimulator:
        self.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self.stop()

    # Faults -------------------------------------------------------------

    def inject(self, fault: FaultName, robot_id: str) -> Ack:
        """Inject ``fault`` into a robot (see ``robocloud.sim.control``)."""
        robot = self._by_id.get(robot_id)
        if robot is None:
            return Ack.refuse(robot_id, None, f"there is no robot {robot_id} in {self.cloud}.")
        with self._lock:
            if fault == "silent":
                robot.silent = True
            elif fault == "recover":
                robot.silent = False
                robot.dirty = True
            else:
                robot.kill_battery(time.time())
        logger.info("fault %s injected into %s", fault, robot_id)
        return Ack(ok=True, robot=robot_id)

    # Simulation -------------------------------------------------------------

    def step(self, sim_seconds: float) -> None:
        """Advance every robot ``sim_seconds`` and publish what is due."""
        wall = time.time()
        mono = time.monotonic()
        batched = self._batches is not None
        outgoing: list[tuple[int, State | WireState]] = []
        with self._lock:
            self._churn.step(self._robots, sim_seconds)
            published = set()
            for i, robot in enumerate(self._robots):
                if robot.job is None and robot.background is None and not robot.dirty:
                    continue
                changes = robot.advance(sim_seconds, wall)
                if robot.dirty and not changes:
                    changes.append(robot.state(wall))
                robot.dirty = False
                if changes and not robot.silent:
                    outgoing.extend((i, state) for state in changes)
                    published.add(i)
            due = np.flatnonzero(self._next_publish <= mono)
            self._next_publish[due] = mono + PUBLISH_PERIOD
            for i in due.tolist():
                robot = self._robots[i]
                if i not in published and not robot.silent:
                    outgoing.append((i, robot.wire_state(wall) if batched else robot.state(wall)))
        self.states_published += len(outgoing)
        if self._batches is not None:
            self._publish_batches(self._batches, [state for _, state in outgoing])
            return
        for i, state in outgoing:
            assert isinstance(state, State)
            self._publishers[i].put(state.model_dump_json())

    def _publish_batches(self, publisher: zenoh.Publisher, states: list[State | WireState]) -> None:
        wire = [s.model_dump(mode="json") if isinstance(s, State) else s for s in states]
        for start in range(0, len(wire), self.batch_size):
            publisher.put(encode_batch(wire[start : start + self.batch_size]))

    def _loop(self) -> None:
        last = time.monotonic()
        deadline = last + self.tick
        while not self._stop.wait(max(0.0, deadline - time.monotonic())):
            now = time.monotonic()
            try:
                self.step((now - last) * self.speedup)
            except zenoh.ZError:
                if self._stop.is_set() or self._session.is_closed():
                    return
                logger.exception("the simulation could not publish")
            except Exception:
                logger.exception("a simulation step failed")
            last = now
            self.ticks += 1
            deadline += self.tick
            if deadline < time.monotonic():
                # Fell behind: skip the missed ticks, the next step covers their time.
                self.late_ticks += 1
                deadline = time.monotonic() + self.tick

    # Zenoh callbacks (on Zenoh's threads) ---------------------------------

    def _on_command(self, query: zenoh.Query) -> None:
        with query:
            robot_id = keys.robot_of(str(query.key_expr))
            robot = self._by_id.get(robot_id) if robot_id is not None else None
            if robot is None or robot.silent:
                return  # not ours, or its radio is off: no answer at all
            ack = self._execute(robot, query.payload)
            if ack is not None:
                key = keys.cmd_key(self.cloud, robot.id)
                query.reply(key, ack.model_dump_json(), encoding=_JSON)

    def _execute(self, robot: SimRobot, payload: zenoh.ZBytes | None) -> Ack | None:
        try:
            command = COMMAND.validate_json(payload.to_bytes() if payload is not None else b"")
        except pydantic.ValidationError as error:
            sentence = describe_validation_errors(error.errors(), prefix="command").message
            return Ack.refuse(robot.id, None, sentence)
        with self._lock:
            if robot.silent:
                return None
            match command:
                case Assign():
                    ack = robot.assign(command)
                case Cancel():
                    ack = robot.cancel(command.request_id)
                case Start():
                    ack = robot.start(command.request_id)
            counted = (command.type, "accepted" if ack.ok else "refused")
            self.commands_answered[counted] = self.commands_answered.get(counted, 0) + 1
        logger.debug("%s %s -> %s", robot.id, command.type, ack)
        return ack

    def _on_control(self, query: zenoh.Query) -> None:
        with query:
            payload = query.payload
            try:
                fault = Fault.model_validate_json(payload.to_bytes() if payload else b"")
            except pydantic.ValidationError as error:
                sentence = describe_validation_errors(error.errors(), prefix="fault").message
                ack = Ack.refuse("simulator", None, sentence)
            else:
                ack = self.inject(fault.fault, fault.robot)
            query.reply(keys.sim_control(self.cloud), ack.model_dump_json(), encoding=_JSON)


def _sim_robot(data: Mapping[str, Any] | Robot, index: int) -> SimRobot:
    try:
        return SimRobot.from_json(data)
    except pydantic.ValidationError as error:
        raise describe_validation_errors(error.errors(), prefix=f"robots[{index}]") from error


def run_simulator(
    cloud: str,
    n_robots: int,
    connect: Sequence[str],
    seed: int = 0,
    speedup: float = 1.0,
    stop_event: threading.Event | None = None,
    *,
    churn: bool = True,
    connect_timeout: float = 10.0,
    security: SessionSecurity | None = None,
    gateway: str | None = None,
    metrics: tuple[str, int] | None = None,
    recharge_below: float | None = None,
) -> None:
    """Simulate ``n_robots`` robots of ``cloud`` connected to the router at ``connect``.

    Runs until ``stop_event`` is set (forever without one). Waits up to
    ``connect_timeout`` seconds for the router. ``security``: TLS or a login
    (``robocloud.federation.security.OverlaySecurity``), as the router asks.
    ``gateway``: publish the states in batches as that gateway (see ``FleetSimulator``).
    ``metrics``: (host, port) to serve Prometheus metrics on (``robocloud.sim.metrics``).
    ``recharge_below``: idle robots below this battery percentage charge (see ``Churn``).
    """
    robots = cloud_robots(cloud, n_robots, seed)
    stop = stop_event or threading.Event()
    session = open_client(connect, timeout=connect_timeout, security=security)
    try:
        with FleetSimulator(
            cloud,
            robots,
            session,
            speedup=speedup,
            seed=seed,
            churn=churn,
            gateway=gateway,
            recharge_below=recharge_below,
        ) as simulator:
            if metrics is not None:
                host, port = metrics
                try:
                    serve_metrics(simulator, host, port)
                except OSError as error:
                    raise InvalidInput(
                        f"--metrics {host}:{port}: cannot listen there ({error.strerror}).",
                        field="--metrics",
                    ) from None
            stop.wait()
    finally:
        session.close()  # type: ignore[no-untyped-call]
