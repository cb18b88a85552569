"""The VDA 5050 gateway: the AGVs of an MQTT broker, robots of a cloud on Zenoh.

::

    MQTT broker (<if>/v2/<m>/<sn>/...)      gateway             IaaS (robocloud/<cloud>/robots/...)
    connection, state, factsheet,       ->  an Agv each    ->  <m>.<sn>/state
    visualization
    order, instantActions               <-  assign, cancel <-  <m>.<sn>/cmd (a queryable each)

Each AGV is the robot ``<manufacturer>.<serialNumber>``. It appears once its
first state with a position has arrived, publishes a state at least twice a
second and at once when its status or its task's phase changes, and is
dropped after ``FORGET_AFTER`` seconds offline. An assign becomes an order
(``messages.order``) and is acknowledged ok once the AGV's state shows it, or
after ``ACCEPT_WAIT`` seconds without a word against it; the task fails (and
the order is cancelled) if the AGV's state has not shown it within
``Timing.accept_within``. A cancel becomes the instant action ``cancelOrder``.
An AGV without a factsheet is asked for one (``factsheetRequest``). What the
AGV says is checked as ``agv.py`` tells (order of states, acceptance,
reconciliation after a restart, liveliness); the counts are the gateway's
metrics (``metrics.py``).

Callbacks come on paho's network thread (MQTT) and on Zenoh's threads
(commands); one condition guards the AGVs, and nothing is sent while it is
held. A bad or partial message is logged with a sentence (once a minute per
topic) and dropped; nothing a broker says stops the gateway.
"""

from __future__ import annotations

import json
import logging
import math
import re
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import paho.mqtt.client as mqtt
import pydantic
from paho.mqtt.enums import CallbackAPIVersion

from robocloud.domain.robot import NAME_PATTERN
from robocloud.errors import InvalidInput, Unavailable, describe_validation_errors
from robocloud.fleet import keys
from robocloud.fleet.behaviour import refuse_cancel
from robocloud.fleet.messages import Ack, Assign, Cancel, State
from robocloud.gateways.vda5050 import messages as vda
from robocloud.gateways.vda5050.agv import Agv, BadMessage, Stale, Timing
from robocloud.gateways.vda5050.capabilities import GatewayCapabilities
from robocloud.gateways.zenoh_side import CommandHandler, RobotSide

log = logging.getLogger(__name__)

TICK = 0.1  # seconds between two looks at what to publish
PUBLISH_EVERY = 0.5  # seconds: each robot's state at least this often
ACCEPT_WAIT = 1.0  # seconds an assign waits for the AGV's state to show the order
FACTSHEET_AGAIN = 30.0  # seconds between two factsheet requests to one AGV
FORGET_AFTER = 600.0  # seconds offline after which an AGV is no longer a robot
MAX_AGVS = 10_000
MAX_PAYLOAD = 1024 * 1024  # bytes of one MQTT message (a factsheet may be large)
COMPLAIN_EVERY = 60.0  # seconds between two log lines about one topic
MODELS: dict[str, type[pydantic.BaseModel]] = {
    "connection": vda.Connection,
    "state": vda.VdaState,
    "factsheet": vda.Factsheet,
    "visualization": vda.Visualization,
}


@dataclass(frozen=True)
class Numbers:
    statuses: dict[str, int]
    stale: int
    not_accepted: int
    reconcile_cancels: int


def robot_id(name: vda.AgvName) -> str | None:
    """``<manufacturer>.<serialNumber>``, or None when that cannot be a robot id."""
    candidate = f"{name.manufacturer}.{name.serial}"
    try:
        keys.check_chunk(candidate, "robot")
    except InvalidInput:
        return None
    if len(candidate) > 128 or not re.fullmatch(NAME_PATTERN, candidate):
        return None
    return candidate


class Vda5050Gateway:
    """The AGVs on ``mqtt_host:mqtt_port`` as robots of a cloud.

    ``robots`` makes the Zenoh side from the gateway's command handler (a
    ``ZenohRobots`` on a client session, in ``command.run_gateway``).
    """

    def __init__(
        self,
        robots: Callable[[CommandHandler], RobotSide],
        mqtt_host: str,
        mqtt_port: int,
        capabilities: GatewayCapabilities,
        *,
        interface: str = "uagv",
        major: str = vda.MAJOR,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
        timing: Timing | None = None,
    ) -> None:
        self.robots = robots(self._on_command)
        self.cloud = self.robots.cloud
        self.host, self.port = mqtt_host, mqtt_port
        self.capabilities = capabilities
        self.interface, self.major = interface, major
        self.clock, self.wall = clock, wall
        self.timing = timing or Timing()
        # Counters of the AGVs' misdeeds (metrics.py); written under ``_changed``.
        self.stale_states = 0
        self.orders_not_accepted = 0
        self.reconcile_cancels = 0
        self._agvs: dict[vda.AgvName, Agv] = {}
        self._by_robot: dict[str, Agv] = {}
        self._changed = threading.Condition()
        self._headers = vda.Headers()
        self._complained: dict[str, float] = {}
        self._connected = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        client_id = f"robocloud-{self.cloud}-{secrets.token_hex(4)}"
        self._mqtt = mqtt.Client(
            CallbackAPIVersion.VERSION2, client_id=client_id, protocol=mqtt.MQTTv311
        )
        self._mqtt.on_connect = self._on_connect
        self._mqtt.on_message = self._on_message
        self._mqtt.reconnect_delay_set(1, 5)
        self.sent: list[tuple[str, dict[str, Any]]] = []  # every message sent (for tests)

    # -- life cycle ----------------------------------------------------------------

    def start(self, timeout: float = 10.0) -> None:
        """Connect to the broker and subscribe; Unavailable when it cannot be reached."""
        try:
            self._mqtt.connect(self.host, self.port, keepalive=30)
        except OSError as error:
            raise Unavailable(
                f"cannot reach the MQTT broker at {self.host}:{self.port}: "
                f"{error.strerror or error}."
            ) from None
        self._mqtt.loop_start()
        if not self._connected.wait(timeout):
            self._mqtt.loop_stop()
            raise Unavailable(
                f"the MQTT broker at {self.host}:{self.port} did not accept the gateway "
                f"within {timeout:g} s."
            )
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="vda5050-publish", daemon=True)
        self._thread.start()

    @property
    def running(self) -> bool:
        return self._thread is not None

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
            self._thread = None
        self._mqtt.disconnect()
        self._mqtt.loop_stop()
        self.robots.close()

    def __enter__(self) -> Vda5050Gateway:
        self.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self.stop()

    def robot_ids(self) -> list[str]:
        with self._changed:
            return sorted(self._by_robot)

    def numbers(self) -> Numbers:
        """The counts of metrics.py, now."""
        now = self.clock()
        with self._changed:
            statuses: dict[str, int] = {}
            for agv in self._agvs.values():
                if agv.vda is not None:
                    status = agv.status(now)
                    statuses[status] = statuses.get(status, 0) + 1
            return Numbers(
                statuses, self.stale_states, self.orders_not_accepted, self.reconcile_cancels
            )

    # -- MQTT in --------------------------------------------------------------------

    def _on_connect(
        self,
        client: mqtt.Client,
        userdata: object,
        flags: object,
        reason: Any,
        properties: object,
    ) -> None:
        if getattr(reason, "is_failure", False):
            log.warning("the MQTT broker refused the gateway: %s", reason)
            return
        for what in vda.READ:
            qos = 1 if what == "connection" else 0
            client.subscribe(f"{self.interface}/{self.major}/+/+/{what}", qos=qos)
        log.info("connected to the MQTT broker at %s:%d", self.host, self.port)
        self._connected.set()

    def _on_message(self, client: mqtt.Client, userdata: object, msg: mqtt.MQTTMessage) -> None:
        try:
            self._message(msg.topic, bytes(msg.payload))
        except BadMessage as error:
            why = str(error).rstrip(".")  # a validation sentence ends with its own full stop
            self._complain(msg.topic, f"ignoring the message on {msg.topic}: {why}.")
        except Exception:  # nothing a broker says stops the gateway
            log.exception("a message on %s could not be handled", msg.topic)

    def _message(self, topic: str, payload: bytes) -> None:
        parsed = vda.parse_topic(topic, self.interface, self.major)
        if parsed is None:
            return
        name, what = parsed
        model = MODELS.get(what)
        if model is None:
            return
        if not payload:
            return  # a retained message cleared
        if len(payload) > MAX_PAYLOAD:
            raise BadMessage(f"it is {len(payload)} bytes, over the {MAX_PAYLOAD} accepted")
        try:
            message = model.model_validate_json(payload)
        except pydantic.ValidationError as error:
            raise BadMessage(describe_validation_errors(error.errors(), what).message) from None
        ask_factsheet = False
        with self._changed:
            agv = self._agv(name, topic)
            if agv is None:
                return
            now, wall = self.clock(), self.wall()
            if isinstance(message, vda.Connection):
                agv.on_connection(message.connectionState, now)
            elif isinstance(message, vda.VdaState):
                try:
                    agv.on_state(message, now, wall)
                except Stale:
                    self.stale_states += 1
                    raise
            elif isinstance(message, vda.Factsheet):
                agv.on_factsheet(message, now, wall)
            elif isinstance(message, vda.Visualization):
                agv.on_visualization(message.agvPosition, now, wall)
            if agv.factsheet is None and agv.connection == "ONLINE":
                ask_factsheet = now - agv.factsheet_asked > FACTSHEET_AGAIN
                if ask_factsheet:
                    agv.factsheet_asked = now
            notes, cancels = self._drain(agv)
            self._changed.notify_all()
        self._tell(notes, cancels)
        if ask_factsheet:
            self._send(name, "instantActions", vda.factsheet_request(
                self._headers.header(name, "instantActions", self.wall()),
                f"factsheet-{secrets.token_hex(4)}",
            ))  # fmt: skip

    def _agv(self, name: vda.AgvName, topic: str) -> Agv | None:
        """The AGV of ``name`` (the caller holds the lock); made on first sight."""
        agv = self._agvs.get(name)
        if agv is not None:
            return agv
        rid = robot_id(name)
        if rid is None:
            self._complain(
                topic,
                f"ignoring {topic}: {name.manufacturer}.{name.serial} cannot be a robot id "
                "(1 to 128 printable characters, none of / * $ ? #).",
            )
            return None
        other = self._by_robot.get(rid)
        if other is not None:
            # "dup"/"x.1" and "dup.x"/"1" are both dup.x.1: one robot must not be two AGVs.
            self._complain(
                topic,
                f"ignoring {topic}: it would be robot {rid}, which the AGV "
                f"{other.name.manufacturer}/{other.name.serial} is already.",
            )
            return None
        if len(self._agvs) >= MAX_AGVS:
            self._complain("max", f"ignoring {topic}: the gateway has {MAX_AGVS} AGVs already.")
            return None
        agv = Agv(name, rid, self.timing)
        self._agvs[name] = agv
        self._by_robot[rid] = agv
        return agv

    def _complain(self, topic: str, sentence: str) -> None:
        now = self.clock()
        with self._changed:
            if now - self._complained.get(topic, -math.inf) < COMPLAIN_EVERY:
                return
            if len(self._complained) >= MAX_AGVS:
                self._complained.clear()
            self._complained[topic] = now
        log.warning("%s", sentence)

    def _drain(self, agv: Agv) -> tuple[list[str], list[tuple[vda.AgvName, str, str]]]:
        """What ``agv`` asks to log and to cancel, and its counts (the caller holds the lock)."""
        notes, agv.notes = agv.notes, []
        cancels = [(agv.name, order, why) for order, why in agv.cancels]
        agv.cancels = []
        self.orders_not_accepted += agv.not_accepted
        agv.not_accepted = 0
        self.reconcile_cancels += len(cancels)
        return notes, cancels

    def _tell(self, notes: list[str], cancels: list[tuple[vda.AgvName, str, str]]) -> None:
        """Log the notes and send the cancelOrders (the lock is not held)."""
        for note in notes:
            log.warning("%s", note)
        for name, order, why in cancels:
            header = self._headers.header(name, "instantActions", self.wall())
            self._send(name, "instantActions", vda.cancel_order(
                header, f"{order}-cancel-{secrets.token_hex(2)}"))  # fmt: skip
            log.warning(
                "AGV %s.%s: sent cancelOrder for order %s: %s",
                name.manufacturer, name.serial, order, why,
            )  # fmt: skip

    # -- MQTT out -------------------------------------------------------------------

    def _send(self, name: vda.AgvName, what: str, message: dict[str, Any]) -> None:
        topic = name.topic(self.interface, self.major, what)
        self._mqtt.publish(topic, json.dumps(message), qos=0)
        self.sent.append((topic, message))
        if len(self.sent) > 1000:
            del self.sent[:500]

    # -- Zenoh in: commands -------------------------------------------------------------

    def _on_command(self, robot: str, command: Assign | Cancel) -> Ack:
        rid = command.request_id
        with self._changed:
            agv = self._by_robot.get(robot)
            if agv is None:
                return Ack.refuse(robot, rid, f"the gateway has no AGV {robot}.")
            now = self.clock()
            if isinstance(command, Cancel):
                current = agv.job.request_id if agv.job is not None else None
                refusal = refuse_cancel(robot, current, rid)
                if refusal is not None:
                    return Ack.refuse(robot, rid, refusal)
                job = agv.cancel()
                order_id = job.order_id if job is not None else agv.still_running(rid)
                if order_id is None:
                    return Ack(ok=True, robot=robot, request_id=rid)
                agv.cancelling(order_id, now)
                header = self._headers.header(agv.name, "instantActions", self.wall())
                message = vda.cancel_order(header, f"{order_id}-cancel-{secrets.token_hex(2)}")
                name = agv.name
            else:
                refusal = agv.refuse(command, self.capabilities, now)
                if refusal is not None:
                    return Ack.refuse(robot, rid, refusal)
                if agv.job is not None:  # the same request again: it is on it
                    return Ack(ok=True, robot=robot, request_id=rid)
                actions = agv.take(command, self.capabilities, now)
                job = agv.job
                assert job is not None
                header = self._headers.header(agv.name, "order", self.wall())
                message = vda.order(
                    header, job.order_id, job.start, job.target, agv.map_id, actions
                )
                name = agv.name
        if isinstance(command, Cancel):
            self._send(name, "instantActions", message)
            log.info("%s cancel: sent cancelOrder for %s", robot, order_id)
            return Ack(ok=True, robot=robot, request_id=rid)
        self._send(name, "order", message)
        log.info("%s assign: sent order %s", robot, job.order_id)
        with self._changed:
            self._changed.wait_for(lambda: job.accepted or agv.job is not job, ACCEPT_WAIT)
            if agv.job is not job:
                why = agv.rejection(job.order_id) or "the AGV dropped the order"
                return Ack.refuse(robot, rid, f"AGV {robot} did not take the order: {why}.")
        return Ack(ok=True, robot=robot, request_id=rid)

    # -- Zenoh out: states ----------------------------------------------------------------

    def _loop(self) -> None:
        while not self._stop.wait(TICK):
            try:
                self.publish_due()
            except Exception:
                log.exception("publishing the AGVs' states failed")

    def publish_due(self) -> None:
        """Publish each robot whose state changed or is due; forget AGVs offline too long."""
        now, wall = self.clock(), self.wall()
        states: list[State] = []
        gone: list[str] = []
        notes: list[str] = []
        cancels: list[tuple[vda.AgvName, str, str]] = []
        with self._changed:
            for name, agv in list(self._agvs.items()):
                if agv.offline_since is not None and now - agv.offline_since > FORGET_AFTER:
                    del self._agvs[name], self._by_robot[agv.robot_id]
                    gone.append(agv.robot_id)
                    continue
                agv.tick(now)
                said, due = self._drain(agv)
                notes += said
                cancels += due
                if not agv.dirty and now - agv.published_at < PUBLISH_EVERY:
                    continue
                state = agv.state(self.cloud, self.capabilities, now, wall)
                if state is None:
                    continue
                agv.dirty, agv.published_at = False, now
                states.append(state)
        self._tell(notes, cancels)
        for robot in gone:
            log.info("forgot AGV %s, offline for over %.0f s", robot, FORGET_AFTER)
            self.robots.remove(robot)
        for state in states:
            if not self.robots.has(state.id):
                self.robots.add(state.id)
                log.info("AGV %s is robot %s of %s", state.id, state.id, self.cloud)
            self.robots.publish(state)
