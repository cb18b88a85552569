"""A stand-in ROS 2 robot with Nav2 on Zenoh: ``StandinRobot`` (run by ``standin.py``).

What it does, from the ROS 2 and Nav2 documentation:

- publishes ``/tf`` (map -> odom -> base_link; odom sits at (1, 0.5) in the
  map, so a reader must compose the two; ``--no-map-tf`` leaves map -> odom
  out), ``amcl_pose`` twice a second, ``battery_state`` once a second,
  and while a goal runs ``navigate_to_pose/_action/feedback`` (distance and
  estimated time remaining) and ``.../status`` on every change;
- serves ``send_goal`` (accepts, drives straight to the pose at ``--speed``),
  ``get_result`` (held until the goal ends, then the status and the distro's
  result: Humble's empty one, Jazzy's error code and message) and
  ``cancel_goal`` (by goal id and stamp, as action_msgs/CancelGoal says);
- on rmw_zenoh: keys with the DDS type and a type hash (Humble's
  ``TypeHashNotSupported``; from Jazzy on a hash made here, which the gateway
  learns from the liveliness tokens like any other), liveliness tokens for
  its node, services and publishers, and the 33-byte attachment on each
  sample and reply; each request's attachment is checked strictly (33
  bytes, a 16-byte GID, the sequence number strictly increasing per client),
  and a request that fails is logged and not answered.

Knobs, sent as JSON to the queryable ``robocloud-standin/<name>/control`` on
the robot's router: ``{"do": "preempt"}`` (another user's goal replaces
ours, which is aborted), ``{"do": "nav2_down"}`` (the action server goes
away: tokens and queryables undeclared, held get_results ended without a
reply; tf and battery go on), ``{"do": "nav2_up"}``, ``{"do": "abort"}``.
``--distro lyrical`` appends two fields to the feedback; a gateway told the
robot is Humble or Jazzy must refuse it.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import math
import secrets
import struct
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from robocloud.gateways.ros2 import interfaces as ros
from robocloud.gateways.ros2 import naming
from robocloud.gateways.ros2 import standin_cdr as m

log = logging.getLogger("robocloud.ros2.standin")

ODOM_IN_MAP = (1.0, 0.5)  # where odom's origin is in the map frame
NODE = "bt_navigator"
GOAL_RADIUS = 0.05  # metres: arrived


@dataclass
class Goal:
    goal_id: bytes
    target: tuple[float, float]
    ours: bool = True  # sent over Zenoh (False: the "other user" of a preemption)
    status: int = ros.STATUS_EXECUTING
    stamp: float = field(default_factory=time.time)
    started: float = field(default_factory=time.monotonic)
    waiting: list[zenoh.Query] = field(default_factory=list)  # held get_result queries


class StandinRobot:
    def __init__(self, args: argparse.Namespace, listen: str, namespace: str, index: int) -> None:
        self.args, self.listen, self.namespace = args, listen, namespace
        self.name = namespace.strip("/").replace("/", "_") or "root"
        self.scheme, self.distro, self.domain = args.scheme, args.distro, args.domain
        self.x, self.y = args.x + 3.0 * index, args.y
        self.battery = args.battery
        self.lock = threading.Lock()
        self.goals: dict[bytes, Goal] = {}
        self.active: Goal | None = None
        self.nav2_up = False
        self.seen_seq: dict[bytes, int] = {}  # client GID -> its last sequence number
        self.pub_seq = 0
        self.gid = secrets.token_bytes(16)
        self.log_file = Path(args.log) if args.log and index == 0 else None
        config = zenoh.Config()
        config.insert_json5("mode", '"router"')
        config.insert_json5("listen/endpoints", json.dumps([listen]))
        config.insert_json5("scouting/multicast/enabled", "false")
        config.insert_json5("scouting/delay", "0")
        self.session = zenoh.open(config)
        self.zid = str(self.session.zid())
        self.server: list[Any] = []
        self.always: list[Any] = []
        self._declare_always()
        self.set_nav2(True)

    # -- names --------------------------------------------------------------------------

    def type_hash(self, part: str) -> str:
        if self.distro == "humble":
            return naming.NO_HASH
        digest = hashlib.sha256(f"{self.distro}:{ros.DDS_NAMES[part]}".encode()).hexdigest()
        return f"RIHS01_{digest}"

    def ros_name(self, part: str) -> str:
        if part == "tf":
            return "tf"
        if part == "battery":
            return "battery_state"
        if part == "amcl":
            return "amcl_pose"
        return naming.action_entity("navigate_to_pose", part)

    def key(self, part: str) -> str:
        name = self.ros_name(part)
        if self.scheme == "bridge":
            return naming.bridge_key(self.namespace, name)
        return naming.rmw_key(self.domain, self.namespace, name, ros.DDS_NAMES[part],
                              self.type_hash(part))  # fmt: skip

    def token(self, part: str, kind: str, entity: int) -> str:
        return naming.token_key(
            self.domain, self.zid, 0, entity, kind, self.namespace, NODE,
            "/" + naming.full_name(self.namespace, self.ros_name(part)),
            ros.DDS_NAMES[part], self.type_hash(part),
        )  # fmt: skip

    def attachment(self, seq: int | None = None) -> bytes | None:
        if self.scheme == "bridge":
            return None
        if seq is None:
            self.pub_seq += 1
            seq = self.pub_seq
        attachment = naming.Attachment(seq, time.time_ns(), self.gid)
        return (
            naming.encode_keyed_attachment(attachment)
            if self.args.old_attachment
            else _pack(attachment)
        )

    # -- declarations -------------------------------------------------------------------

    def _declare_always(self) -> None:
        s = self.session
        if self.scheme == "rmw_zenoh":
            node = naming.token_key(self.domain, self.zid, 0, 0, "NN", self.namespace, NODE)
            self.always.append(s.liveliness().declare_token(node))
            for i, part in enumerate(("tf", "battery", "amcl"), start=1):
                self.always.append(s.liveliness().declare_token(self.token(part, "MP", i)))
        self.always.append(s.declare_queryable(
            f"robocloud-standin/{self.name}/control", self._on_control
        ))  # fmt: skip

    def set_nav2(self, up: bool) -> None:
        with self.lock:
            if up == self.nav2_up:
                return
            self.nav2_up = up
            if not up:
                held = [q for g in self.goals.values() for q in g.waiting]
                for g in self.goals.values():
                    g.waiting = []
                self.active = None  # bt_navigator died: nobody drives
                server, self.server = self.server, []
        if not up:
            for query in held:
                query.drop()  # type: ignore[no-untyped-call]  # ends without a reply, as when the server's process dies
            for entity in server:
                entity.undeclare()
            self.record({"event": "nav2_down"})
            return
        s = self.session
        handlers = {"send_goal": self._on_send_goal, "get_result": self._on_get_result,
                    "cancel_goal": self._on_cancel}  # fmt: skip
        server = [s.declare_queryable(self.key(p), h, complete=True) for p, h in handlers.items()]
        if self.scheme == "rmw_zenoh":
            for i, part in enumerate(naming.SERVICES, start=10):
                server.append(s.liveliness().declare_token(self.token(part, "SS", i)))
            for i, part in enumerate(naming.ACTION_TOPICS, start=20):
                server.append(s.liveliness().declare_token(self.token(part, "MP", i)))
        with self.lock:
            self.server = server
        self.record({"event": "nav2_up"})

    def record(self, event: dict[str, Any]) -> None:
        if self.log_file is not None:
            with self.log_file.open("a") as f:
                f.write(json.dumps({**event, "t": time.time()}) + "\n")

    # -- requests -------------------------------------------------------------------------

    def _check_request(self, service: str, query: zenoh.Query) -> naming.Attachment | bool | None:
        """The request's attachment (rmw_zenoh), True for a bridge, False when refused."""
        if self.scheme == "bridge":
            return True
        raw = query.attachment.to_bytes() if query.attachment is not None else b""
        problem = None
        if len(raw) != naming.ATTACHMENT_SIZE:
            problem = f"the attachment is {len(raw)} bytes, not {naming.ATTACHMENT_SIZE}"
        else:
            attachment = naming.decode_attachment(raw)
            last = self.seen_seq.get(attachment.gid, 0)
            if attachment.sequence_number <= last:
                problem = (f"sequence number {attachment.sequence_number} after {last} "
                           "from the same client")  # fmt: skip
            elif abs(attachment.source_timestamp / 1e9 - time.time()) > 60:
                problem = "the source timestamp is over a minute off"
            else:
                self.seen_seq[attachment.gid] = attachment.sequence_number
                return attachment
        self.record({"event": "bad_request", "service": service, "problem": problem})
        log.warning("%s: refused a %s request: %s", self.name, service, problem)
        return False

    def _reply(self, query: zenoh.Query, service: str, payload: bytes, request: Any) -> None:
        seq = request.sequence_number if isinstance(request, naming.Attachment) else None
        query.reply(self.key(service), payload, attachment=self.attachment(seq))

    def _on_send_goal(self, query: zenoh.Query) -> None:
        with query:
            checked = self._check_request("send_goal", query)
            if checked is False or query.payload is None:
                return
            request = m.SendGoalRequest.deserialize(query.payload.to_bytes())
            goal_id = m.raw_uuid(request.goal_id)
            position = request.goal.pose.pose.position
            q = request.goal.pose.pose.orientation
            norm = math.sqrt(q.x**2 + q.y**2 + q.z**2 + q.w**2)
            frame = request.goal.pose.header.frame_id
            accepted = abs(norm - 1.0) < 1e-6 and frame == "map"
            self.record({"event": "send_goal", "goal_id": goal_id.hex(), "x": position.x,
                         "y": position.y, "frame": frame, "accepted": accepted})  # fmt: skip
            if accepted:
                with self.lock:
                    self._replace(Goal(goal_id, (position.x, position.y)))
            response = m.SendGoalResponse(accepted, _time(time.time()))
            self._reply(query, "send_goal", m.encode(response), checked)
        self.publish_status()

    def _replace(self, goal: Goal) -> None:
        """A new goal preempts the running one, which is aborted (the caller holds the lock)."""
        if self.active is not None and self.active.status in (1, 2):
            self._end(self.active, ros.STATUS_ABORTED, 9001, "preempted by a new goal")
        self.goals[goal.goal_id] = goal
        self.active = goal

    def _end(self, goal: Goal, status: int, code: int = 0, message: str = "") -> None:
        """The goal ends: every held get_result gets its answer (the caller holds the lock)."""
        goal.status = status
        if self.active is goal:
            self.active = None
        for query in goal.waiting:
            self._answer_result(query, goal, code, message)
        goal.waiting = []

    def _answer_result(
        self, query: zenoh.Query, goal: Goal, code: int = 0, message: str = ""
    ) -> None:
        if self.distro == "humble":
            response: Any = m.HumbleGetResultResponse(goal.status)
        else:
            response = m.JazzyGetResultResponse(goal.status, m.JazzyResult(code, message))
        query.reply(self.key("get_result"), m.encode(response), attachment=self.attachment())
        query.drop()  # type: ignore[no-untyped-call]

    def _on_get_result(self, query: zenoh.Query) -> None:
        if self._check_request("get_result", query) is False or query.payload is None:
            query.drop()  # type: ignore[no-untyped-call]
            return
        request = m.GetResultRequest.deserialize(query.payload.to_bytes())
        goal_id = m.raw_uuid(request.goal_id)
        with self.lock:
            goal = self.goals.get(goal_id)
            if goal is None:
                query.drop()  # type: ignore[no-untyped-call]
                return
            if goal.status in (1, 2, 3):
                goal.waiting.append(query)  # held until the goal ends
                if self.args.result_timeout:  # as a bridge's queries_timeout would
                    timer = threading.Timer(self.args.result_timeout, self._expire, (goal, query))
                    timer.daemon = True
                    timer.start()
                return
            self._answer_result(query, goal)

    def _expire(self, goal: Goal, query: zenoh.Query) -> None:
        with self.lock:
            if query not in goal.waiting:
                return
            goal.waiting.remove(query)
        self.record({"event": "get_result_timeout", "goal_id": goal.goal_id.hex()})
        query.drop()  # type: ignore[no-untyped-call]

    def _on_cancel(self, query: zenoh.Query) -> None:
        with query:
            checked = self._check_request("cancel_goal", query)
            if checked is False or query.payload is None:
                return
            request = m.CancelGoalRequest.deserialize(query.payload.to_bytes())
            goal_id = m.raw_uuid(request.goal_info.goal_id)
            stamp = request.goal_info.stamp.sec + request.goal_info.stamp.nanosec / 1e9
            self.record(
                {
                    "event": "cancel_goal",
                    "goal_id": goal_id.hex(),
                    "stamp": [request.goal_info.stamp.sec, request.goal_info.stamp.nanosec],
                }
            )
            canceling = []
            with self.lock:
                for goal in self.goals.values():
                    if goal.status not in (1, 2):
                        continue
                    by_id = goal.goal_id == goal_id or (goal_id == bytes(16) and stamp == 0)
                    by_stamp = stamp > 0 and goal.stamp <= stamp
                    if by_id or by_stamp:
                        canceling.append(m.GoalInfo(m.uuid_of(goal.goal_id), _time(goal.stamp)))
                        self._end(goal, ros.STATUS_CANCELED)
            code = ros.CANCEL_NONE if canceling else ros.CANCEL_UNKNOWN_GOAL
            self._reply(query, "cancel_goal", m.encode(m.cancel_response(code, canceling)), checked)
        self.publish_status()

    def _on_control(self, query: zenoh.Query) -> None:
        with query:
            order = json.loads(query.payload.to_bytes()) if query.payload is not None else {}
            what = order.get("do")
            if what == "preempt":
                with self.lock:
                    other = Goal(secrets.token_bytes(16), (self.x + 2.0, self.y), ours=False)
                    self._replace(other)
                self.record({"event": "preempted", "by": other.goal_id.hex()})
                self.publish_status()
            elif what == "nav2_down":
                self.set_nav2(False)
            elif what == "nav2_up":
                self.set_nav2(True)
            elif what == "abort":
                with self.lock:
                    if self.active is not None:
                        self._end(self.active, ros.STATUS_ABORTED, 104, "no valid path")
                self.publish_status()
            query.reply(query.key_expr, json.dumps({"ok": what is not None}))

    # -- what it publishes -----------------------------------------------------------------

    def put(self, part: str, payload: bytes) -> None:
        self.session.put(self.key(part), payload, attachment=self.attachment())

    def publish_status(self) -> None:
        with self.lock:
            if not self.nav2_up:
                return
            recent = list(self.goals.values())[-4:]
            array = m.status_array([
                m.GoalStatus(m.GoalInfo(m.uuid_of(g.goal_id), _time(g.stamp)), g.status)
                for g in recent
            ])  # fmt: skip
        self.put("status", m.encode(array))

    def publish_tf(self) -> None:
        now = _time(time.time())
        ox, oy = ODOM_IN_MAP
        odom = m.Transform(m.Vector3(ox, oy, 0.0), m.Quaternion())
        base = m.Transform(m.Vector3(self.x - ox, self.y - oy, 0.0), m.Quaternion())
        transforms = [m.TransformStamped(m.Header(now, "odom"), "base_link", base)]
        if not self.args.no_map_tf:  # else only AMCL's pose says where it is in the map
            transforms.insert(0, m.TransformStamped(m.Header(now, "map"), "odom", odom))
        tf = m.tf_message(transforms)
        self.put("tf", m.encode(tf))

    def publish_amcl(self) -> None:
        pose = m.Pose(m.Point(self.x, self.y, 0.0))
        message = m.PoseWithCovarianceStamped(
            m.Header(_time(time.time()), "map"), m.PoseWithCovariance(pose)
        )
        self.put("amcl", m.encode(message))

    def publish_battery(self) -> None:
        battery = m.BatteryState(
            m.Header(_time(time.time()), "base_link"),
            voltage=14.8,
            percentage=self.battery,
            power_supply_status=2,
        )  # discharging
        self.put("battery", m.encode(battery))

    def publish_feedback(self) -> bool:
        with self.lock:
            goal = self.active
            if goal is None or not goal.ours or not self.nav2_up:
                return False
            distance = math.dist((self.x, self.y), goal.target)
            pose = m.PoseStamped(m.Header(_time(time.time()), "map"),
                                 m.Pose(m.Point(self.x, self.y, 0.0)))  # fmt: skip
            values: dict[str, Any] = {
                "current_pose": pose,
                "navigation_time": m.duration(time.monotonic() - goal.started),
                "estimated_time_remaining": m.duration(distance / self.args.speed),
                "distance_remaining": distance,
            }
            if self.distro == "lyrical":
                message: Any = m.LyricalFeedbackMessage(m.uuid_of(goal.goal_id),
                                                        m.LyricalFeedback(**values))  # fmt: skip
            else:
                message = m.FeedbackMessage(m.uuid_of(goal.goal_id), m.Feedback(**values))
        self.put("feedback", m.encode(message))
        return True

    def step(self, dt: float) -> bool:
        """Drive toward the active goal; True when a goal ended (status to publish)."""
        with self.lock:
            goal = self.active
            if goal is None:
                return False
            dx, dy = goal.target[0] - self.x, goal.target[1] - self.y
            distance = math.hypot(dx, dy)
            reach = self.args.speed * dt
            if distance <= max(reach, GOAL_RADIUS):
                self.x, self.y = goal.target
                self._end(goal, ros.STATUS_SUCCEEDED)
                return True
            self.x += dx / distance * reach
            self.y += dy / distance * reach
            return False

    def close(self) -> None:
        self.set_nav2(False)
        self.session.close()  # type: ignore[no-untyped-call]


def _time(unix: float) -> m.Time:
    whole = int(unix)
    return m.Time(whole, int((unix - whole) * 1e9))


def _pack(attachment: naming.Attachment) -> bytes:
    """The 33-byte attachment, packed here field by field (not with the gateway's encoder)."""
    seq = struct.pack("<q", attachment.sequence_number)
    return seq + struct.pack("<q", attachment.source_timestamp) + bytes([16]) + attachment.gid
