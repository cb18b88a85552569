"""One robot's Zenoh session: its router (rmw_zenoh) or its bridge, and nothing else.

Why one long file: ``RobotLink`` is one session's life (its tokens, topics
and the three action services), all on that session and under one lock; the
robot's state (``robot.py``), the messages (``cdr.py``) and the names
(``naming.py``) are apart already.

The gateway opens one client session per robot to the robot's own endpoint,
so robots stay apart and ROS traffic never reaches the cloud's router. A
``RobotLink`` subscribes to what the gateway reads (``/tf``, the battery,
the action's feedback and status), learns the action server from the
robot's liveliness tokens (rmw_zenoh) or from a queryable matching its
``send_goal`` key (bridge), and sends the goal, get_result and cancel_goal
requests. What it hears goes to ``apply(robot_id, change)``, which the
gateway runs on the robot under its lock; it never holds that lock itself.

Every message the robot sends is decoded for its configured distro; one that
does not decode makes the robot not selectable, with a sentence naming the
type and the distro (``RosRobot.on_fault``). The type hashes of rmw_zenoh's
keys are read from the tokens, never written here.
"""

from __future__ import annotations

import contextlib
import functools
import itertools
import json
import logging
import math
import secrets
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from robocloud.gateways.ros2 import interfaces as ros
from robocloud.gateways.ros2 import naming
from robocloud.gateways.ros2.cdr import CdrError, Codec
from robocloud.gateways.ros2.robot import RosRobot
from robocloud.gateways.ros2.robots_file import RobotEntry

log = logging.getLogger(__name__)

Change = Callable[[RosRobot, float], None]
Apply = Callable[[str, Change], None]

SEND_GOAL_TIMEOUT = 5.0  # seconds for Nav2 to accept or reject a goal
RESULT_TIMEOUT = 7 * 24 * 3600.0  # get_result is held until the goal ends
CANCEL_TIMEOUT = 5.0
RESULT_AGAIN_AFTER = 1.0  # seconds: a get_result that ended sooner without a reply is Nav2 gone
# The topics are not handed to Python sample by sample: Nav2 sends feedback at ~100 Hz
# and /tf comes at 30 Hz or more, while the cloud sees a robot once a second; and a
# robot that floods any topic must not cost the gateway more than one that does not.
# Zenoh keeps the newest few in a ring (the older are dropped there) and ``poll``, run
# ten times a second, reads them: the newest always, an older one only when it differs
# in size (another set of transforms, e.g. map -> odom sent apart from odom -> base_link;
# a status array of other goals). A status lists every recent goal, so the newest
# tells all; a battery is a level.
RINGS = {"tf": 2, "feedback": 1, "status": 2, "battery": 1, "amcl": 1}
COMPLAIN_EVERY = 60.0

# What the gateway reads, by the name of its part: (ROS type in interfaces, DDS name key).
TOPICS = {
    "tf": "tf2_msgs/TFMessage",
    "battery": "sensor_msgs/BatteryState",
    "feedback": "nav2_msgs/NavigateToPose_FeedbackMessage",
    "status": "action_msgs/GoalStatusArray",
    "amcl": "geometry_msgs/PoseWithCovarianceStamped",
}


class ServiceClient:
    """One service client's identity on rmw_zenoh: its GID and a strictly increasing counter."""

    def __init__(self) -> None:
        self.gid = secrets.token_bytes(naming.GID_SIZE)
        self._counter = itertools.count(1)
        self._lock = threading.Lock()

    def attachment(self) -> bytes:
        with self._lock:
            seq = next(self._counter)
        return naming.Attachment(seq, time.time_ns(), self.gid).encode()


class RobotLink:
    def __init__(
        self, robot_id: str, entry: RobotEntry, apply: Apply, codec: Codec | None = None
    ) -> None:
        self.robot_id, self.entry, self._apply = robot_id, entry, apply
        self.codec = codec or Codec(ros.definitions(entry.distro))
        self._trailing = ros.TRAILING_ALLOWED[entry.distro]
        self._session: zenoh.Session | None = None
        self._entities: list[Any] = []
        self._hashes: dict[str, tuple[str, str]] = {}  # part -> (DDS type, hash), from tokens
        self._servers: set[str] = set()  # the action's services whose server is visible
        self._clients = {name: ServiceClient() for name in naming.SERVICES}
        self._rings: dict[str, Any] = {}  # part -> its subscriber with a ring channel
        self._queriers: dict[str, Any] = {}  # a bridge's service -> its querier (matching)
        # Goals sent, Nav2's answer not in yet -> whether a cancel waits for it: a cancel
        # sent before the goal's acceptance could reach Nav2 first and miss the goal.
        self._unanswered: dict[bytes, bool] = {}
        self._complained: dict[str, float] = {}
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._open, name=f"ros2-{robot_id}", daemon=True)

    # -- life cycle ----------------------------------------------------------------

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._closed.set()
        with self._lock:
            session, self._session = self._session, None
            entities, self._entities = self._entities, []
            self._queriers = {}
        for entity in entities:
            with contextlib.suppress(zenoh.ZError):
                entity.undeclare()
        if session is not None:
            with contextlib.suppress(zenoh.ZError):
                session.close()  # type: ignore[no-untyped-call]

    def _open(self) -> None:
        """Connect (waiting for the robot as long as it takes), then declare what is read."""
        config = zenoh.Config()
        config.insert_json5("mode", '"client"')
        config.insert_json5("connect/endpoints", json.dumps([self.entry.endpoint]))
        config.insert_json5("scouting/multicast/enabled", "false")
        config.insert_json5("connect/timeout_ms", "-1")
        config.insert_json5("connect/retry", '{"period_init_ms": 200, "period_max_ms": 1000}')
        try:
            session = zenoh.open(config)
        except zenoh.ZError as error:
            log.error("robot %s: cannot open a session to %s: %s",
                      self.robot_id, self.entry.endpoint, error)  # fmt: skip
            return
        with self._lock:
            if self._closed.is_set():
                session.close()  # type: ignore[no-untyped-call]
                return
            self._session = session
        log.info("robot %s: connected to %s (%s, %s)", self.robot_id, self.entry.endpoint,
                 self.entry.scheme, self.entry.distro)  # fmt: skip
        try:
            self._declare(session)
        except zenoh.ZError as error:
            log.error("robot %s: declaring on %s failed: %s", self.robot_id,
                      self.entry.endpoint, error)  # fmt: skip

    def _declare(self, session: zenoh.Session) -> None:
        e = self.entry
        names = {
            "tf": e.tf_topic,
            "battery": e.battery_topic,
            "feedback": naming.action_entity(e.action, "feedback"),
            "status": naming.action_entity(e.action, "status"),
            "amcl": e.amcl_topic,
        }
        entities: list[Any] = []
        for part, name in names.items():
            if e.scheme == "rmw_zenoh":
                key = naming.rmw_subscription_key(e.domain, e.namespace, name)
            else:
                key = naming.bridge_key(e.namespace, name)
            ring = session.declare_subscriber(key, zenoh.handlers.RingChannel(RINGS[part]))
            entities.append(ring)
            with self._lock:
                self._rings[part] = ring
        if e.scheme == "rmw_zenoh":
            entities.append(session.liveliness().declare_subscriber(
                f"{naming.LIVELINESS}/{e.domain}/**", self._on_token, history=True
            ))  # fmt: skip
        else:
            for service in naming.SERVICES:
                key = naming.bridge_key(e.namespace, naming.action_entity(e.action, service))
                querier = session.declare_querier(key)
                entities.append(querier)
                listener = functools.partial(self._on_matching_status, service)
                entities.append(querier.declare_matching_listener(listener))
                status: Any = querier.matching_status  # a MatchingStatus (the stub says bool)
                self._on_matching(service, bool(status.matching))
                with self._lock:
                    self._queriers[service] = querier
        with self._lock:
            self._entities.extend(entities)

    # -- the action server ---------------------------------------------------------

    def _on_matching_status(self, service: str, status: Any) -> None:
        self._on_matching(service, bool(status.matching))

    def _on_matching(self, service: str, matching: bool) -> None:
        self._server_seen(service, matching, "a queryable on its bridge")

    def _on_token(self, sample: zenoh.Sample) -> None:
        token = naming.parse_token(str(sample.key_expr))
        e = self.entry
        if token is None:
            return
        parts = {
            naming.full_name(e.namespace, naming.action_entity(e.action, s)): s
            for s in (*naming.SERVICES, *naming.ACTION_TOPICS)
        }
        parts[naming.full_name(e.namespace, e.tf_topic)] = "tf"
        parts[naming.full_name(e.namespace, e.battery_topic)] = "battery"
        parts[naming.full_name(e.namespace, e.amcl_topic)] = "amcl"
        part = parts.get(token.name)
        wanted = "SS" if part in naming.SERVICES else "MP"
        if part is None or token.kind != wanted:
            return
        alive = sample.kind == zenoh.SampleKind.PUT
        if alive:
            fault = self._check_token(part, token)
            if fault is not None:
                self._apply(self.robot_id, lambda r, now: r.on_fault(fault, now))
                return
            with self._lock:
                self._hashes[part] = (token.dds_type, token.type_hash)
        if part in naming.SERVICES:
            self._server_seen(part, alive, "its liveliness token")

    def _check_token(self, part: str, token: naming.Token) -> str | None:
        """Why this token says the robot is not what the file says, or None."""
        e = self.entry
        expected = ros.DDS_NAMES[part]
        if token.dds_type != expected:
            return (f"its {part} is of type {token.dds_type}, not {expected} "
                    f"(configured as {e.distro})")  # fmt: skip
        hashed = token.type_hash != naming.NO_HASH
        if e.distro == "humble" and hashed:
            return (
                f"its {expected} has the type hash {token.type_hash[:14]}..., which "
                "Humble does not send: the robot runs a newer distro than humble"
            )
        if e.distro != "humble" and not hashed:
            return (
                f"its {expected} has no type hash ({naming.NO_HASH}), as on Humble, "
                f"but it is configured as {e.distro}"
            )
        return None

    def _server_seen(self, service: str, up: bool, why: str) -> None:
        with self._lock:
            before = self._servers >= set(naming.SERVICES)
            if up:
                self._servers.add(service)
            else:
                self._servers.discard(service)
            after = self._servers >= set(naming.SERVICES)
        if after != before:
            self._apply(self.robot_id, lambda r, now: r.on_server(after, now, why))

    # -- what the robot publishes ----------------------------------------------------

    def _on_sample(self, part: str, sample: zenoh.Sample) -> None:
        try:
            self._sample(part, sample)
        except Exception:  # nothing a robot sends stops the gateway
            log.exception("robot %s: a %s sample could not be handled", self.robot_id, part)

    def poll(self) -> None:
        """Read what the rings of the fast topics hold (see ``RINGS``); for a bridge's
        robot, read its services' matching status again: a full run once saw a bridge
        robot's Nav2 never become visible, its matching listener silent."""
        with self._lock:
            rings = list(self._rings.items())
            queriers = list(self._queriers.items())
        for service, querier in queriers:
            with contextlib.suppress(zenoh.ZError):
                self._on_matching(service, bool(querier.matching_status.matching))
        for part, ring in rings:
            samples = []
            while (sample := ring.try_recv()) is not None:
                samples.append(sample)
            if not samples:
                continue
            newest = samples[-1]
            size = len(newest.payload)
            for sample in samples[:-1]:
                if len(sample.payload) != size:
                    self._on_sample(part, sample)
            self._on_sample(part, newest)

    def _sample(self, part: str, sample: zenoh.Sample) -> None:
        e = self.entry
        if e.scheme == "rmw_zenoh":
            dds_type = str(sample.key_expr).rsplit("/", 2)[-2]
            if dds_type != ros.DDS_NAMES[part]:
                return  # another type on the same name: not ours to read
            if not self._attachment_ok(part, sample.attachment):
                return
        typename = TOPICS[part]
        try:
            message = self.codec.decode(
                typename, sample.payload.to_bytes(), trailing=typename in self._trailing
            )
        except CdrError as error:
            fault = f"its {typename} does not decode as {e.distro} ({error})."
            self._apply(self.robot_id, lambda r, now: r.on_fault(fault, now))
            return
        if part == "tf":
            transforms = [_transform(t) for t in message["transforms"]]
            self._apply(self.robot_id, lambda r, now: r.on_transforms(transforms, now))
        elif part == "battery":
            pct, supply = float(message["percentage"]), int(message["power_supply_status"])
            self._apply(self.robot_id, lambda r, now: r.on_battery(pct, supply, now))
        elif part == "feedback":
            goal = bytes(message["goal_id"]["uuid"])
            fb = message["feedback"]
            eta = fb["estimated_time_remaining"]
            seconds = eta["sec"] + eta["nanosec"] / 1e9
            distance = float(fb["distance_remaining"])
            self._apply(self.robot_id, lambda r, now: r.on_feedback(goal, distance, seconds, now))
        elif part == "amcl":
            pose = message["pose"]["pose"]
            frame = message["header"]["frame_id"]
            x, y = float(pose["position"]["x"]), float(pose["position"]["y"])
            self._apply(self.robot_id, lambda r, now: r.on_amcl(frame, x, y, now))
        elif part == "status":
            statuses = [
                (bytes(s["goal_info"]["goal_id"]["uuid"]), int(s["status"]))
                for s in message["status_list"]
            ]
            self._apply(self.robot_id, lambda r, now: r.on_status(statuses, now))

    def _attachment_ok(self, part: str, attachment: zenoh.ZBytes | None) -> bool:
        if attachment is None:
            self._complain(part, f"robot {self.robot_id}: a {part} sample without rmw_zenoh's "
                                 "attachment was dropped")  # fmt: skip
            return False
        try:
            naming.decode_attachment(attachment.to_bytes())
        except naming.AttachmentError as error:
            self._complain(part, f"robot {self.robot_id}: a {part} sample with a bad "
                                 f"attachment was dropped: {error}")  # fmt: skip
            return False
        return True

    def _complain(self, topic: str, sentence: str) -> None:
        now = time.monotonic()
        with self._lock:
            if now - self._complained.get(topic, -math.inf) < COMPLAIN_EVERY:
                return
            self._complained[topic] = now
        log.warning("%s", sentence)

    # -- requests ----------------------------------------------------------------------

    def _service_key(self, service: str) -> str | None:
        e = self.entry
        name = naming.action_entity(e.action, service)
        if e.scheme == "bridge":
            return naming.bridge_key(e.namespace, name)
        with self._lock:
            learnt = self._hashes.get(service)
        if learnt is None:
            return None
        return naming.rmw_key(e.domain, e.namespace, name, *learnt)

    def _request(
        self,
        service: str,
        payload: bytes,
        timeout: float,
        on_reply: Callable[[bytes], None],
        on_end: Callable[[bool], None],
    ) -> bool:
        """Send a request; ``on_reply(payload)`` per reply, then ``on_end(replied)``."""
        with self._lock:
            session = self._session
        key = self._service_key(service)
        if session is None or key is None:
            return False
        replied = threading.Event()

        def reply(r: zenoh.Reply) -> None:
            if r.ok is None:
                log.warning("robot %s: %s answered an error", self.robot_id, service)
                return
            replied.set()
            try:
                on_reply(r.ok.payload.to_bytes())
            except Exception:
                log.exception("robot %s: the %s reply could not be handled", self.robot_id, service)

        def end() -> None:
            on_end(replied.is_set())

        attachment = (
            self._clients[service].attachment() if self.entry.scheme == "rmw_zenoh" else None
        )
        session.get(
            key,
            zenoh.handlers.Callback(reply, end),
            payload=payload,
            attachment=attachment,
            timeout=timeout,
            target=zenoh.QueryTarget.ALL,
        )
        return True

    def send_goal(self, goal_id: bytes, x: float, y: float) -> None:
        """NavigateToPose to (x, y) in the map frame; then get_result, held until the end."""
        e = self.entry
        request = {
            "goal_id": {"uuid": list(goal_id)},
            "goal": {
                "pose": {
                    "header": {"stamp": _stamp(time.time()), "frame_id": e.map_frame},
                    "pose": {
                        "position": {"x": x, "y": y, "z": 0.0},
                        "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
                    },
                },
                "behavior_tree": "",
            },
        }
        payload = self.codec.encode("nav2_msgs/NavigateToPose_SendGoal_Request", request)

        def on_reply(raw: bytes) -> None:
            with self._lock:
                cancel = self._unanswered.pop(goal_id, False)
            response = self._decode("nav2_msgs/NavigateToPose_SendGoal_Response", raw)
            if response is None:
                return
            accepted = bool(response["accepted"])
            self._apply(self.robot_id, lambda r, now: r.on_goal_response(goal_id, accepted, now))
            if accepted and cancel:
                self.cancel_goal(goal_id)
            elif accepted:
                self._get_result(goal_id)

        def on_end(replied: bool) -> None:
            with self._lock:
                self._unanswered.pop(goal_id, None)
            if not replied:
                self._apply(self.robot_id, lambda r, now: r.on_result_lost(goal_id, now))

        with self._lock:
            self._unanswered[goal_id] = False
        if not self._request("send_goal", payload, SEND_GOAL_TIMEOUT, on_reply, on_end):
            with self._lock:
                self._unanswered.pop(goal_id, None)
            self._apply(self.robot_id, lambda r, now: r.on_result_lost(goal_id, now))

    def _get_result(self, goal_id: bytes) -> None:
        payload = self.codec.encode(
            "nav2_msgs/NavigateToPose_GetResult_Request", {"goal_id": {"uuid": list(goal_id)}}
        )

        def on_reply(raw: bytes) -> None:
            response = self._decode("nav2_msgs/NavigateToPose_GetResult_Response", raw)
            if response is None:
                return
            status, result = int(response["status"]), response["result"]
            detail = ""
            if "error_code" in result and (result["error_code"] or result["error_msg"]):
                detail = f"error {result['error_code']} {result['error_msg']}".strip()
            self._apply(self.robot_id, lambda r, now: r.on_result(goal_id, status, detail, now))

        asked = time.monotonic()

        def on_end(replied: bool) -> None:
            if replied or self._closed.is_set():
                return
            with self._lock:
                up = self._servers >= set(naming.SERVICES)
            if up and time.monotonic() - asked >= RESULT_AGAIN_AFTER:
                # A bridge ends a held query at its own timeout (queries_timeout.actions.
                # get_result, 5 s unless configured) while Nav2 still runs the goal: ask again.
                self._get_result(goal_id)
                return
            self._apply(self.robot_id, lambda r, now: r.on_result_lost(goal_id, now))

        if not self._request("get_result", payload, RESULT_TIMEOUT, on_reply, on_end):
            self._apply(self.robot_id, lambda r, now: r.on_result_lost(goal_id, now))

    def cancel_goal(self, goal_id: bytes) -> None:
        """cancel_goal naming this goal alone: its id, and a zero stamp (no older goals).

        A goal Nav2 has not answered yet is canceled as soon as it is accepted.
        """
        with self._lock:
            if goal_id in self._unanswered:
                self._unanswered[goal_id] = True
                return
        request = {"goal_info": {"goal_id": {"uuid": list(goal_id)}, "stamp": _stamp(0.0)}}
        payload = self.codec.encode("action_msgs/CancelGoal_Request", request)

        def on_reply(raw: bytes) -> None:
            response = self._decode("action_msgs/CancelGoal_Response", raw)
            if response is not None and response["return_code"] != ros.CANCEL_NONE:
                log.info("robot %s: cancel_goal of %s returned %d", self.robot_id,
                         goal_id.hex(), response["return_code"])  # fmt: skip

        sent = self._request("cancel_goal", payload, CANCEL_TIMEOUT, on_reply, lambda _: None)
        if not sent:
            log.warning("robot %s: could not send cancel_goal for %s (no action server)",
                        self.robot_id, goal_id.hex())  # fmt: skip

    def _decode(self, typename: str, raw: bytes) -> dict[str, Any] | None:
        try:
            return self.codec.decode(typename, raw, trailing=typename in self._trailing)
        except CdrError as error:
            fault = f"its {typename} does not decode as {self.entry.distro} ({error})."
            self._apply(self.robot_id, lambda r, now: r.on_fault(fault, now))
            return None


def _stamp(unix: float) -> dict[str, int]:
    whole = int(unix)
    return {"sec": whole, "nanosec": int((unix - whole) * 1e9)}


def _transform(t: dict[str, Any]) -> tuple[str, str, float, float, float]:
    tr, q = t["transform"]["translation"], t["transform"]["rotation"]
    yaw = math.atan2(2 * (q["w"] * q["z"] + q["x"] * q["y"]), 1 - 2 * (q["y"] ** 2 + q["z"] ** 2))
    return t["header"]["frame_id"], t["child_frame_id"], float(tr["x"]), float(tr["y"]), yaw
