"""A VDA 5050 2.x vehicle written from the specification, for the gateway's tests.

It connects to the broker with a last will (``connection`` CONNECTIONBROKEN,
retained), says ONLINE (retained), answers ``factsheetRequest`` with its
factsheet, publishes its state once a second and on every event, drives an
order's nodes in a straight line at ``speed`` and runs the actions of each
node it reaches (SOFT ones together, HARD ones one after the other) for
``action_time`` seconds each, and obeys ``cancelOrder``. Each action it
finishes is logged (``{"did": actionId}``), so a test can count the picks.
Misbehaviour on demand: ``ignore_orders`` (it receives orders but never takes
one: its state never shows them), ``freeze()`` (it stops publishing while its
connection stays up: no last will). Every order and
instant action it receives is checked against the official JSON schemas
(as the PyPI package vda5050-sdk ships them) and kept, with what the schema said.

As a process (so a test can kill it and the broker sends its last will)::

    python vda5050_vehicle.py --interface uagv-x --manufacturer acme --serial agv-1 \
        --x 0 --y 0 --actions pick,drop --log received.jsonl
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import importlib.metadata
import json
import math
import signal
import threading
import time
from pathlib import Path
from typing import Any

import jsonschema_rs
import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion


def official_schemas() -> Path:
    """The VDA 5050 2.1 JSON schemas as the PyPI package ``vda5050-sdk`` ships them.

    The package (a dev dependency) carries copies of the VDA 5050 community's
    schemas; they are read where it installed them, never copied here.
    """
    folder = Path(
        str(
            importlib.metadata.distribution("vda5050-sdk").locate_file("vda5050/validation/schemas")
        )
    )
    if not (folder / "order.json").is_file():
        raise SystemExit(
            f"the VDA 5050 schemas are not at {folder}: install vda5050-sdk (make venv)"
        )
    return folder


SCHEMAS = official_schemas()
VERSION = "2.1.0"


def validator(name: str) -> Any:
    schema = json.loads((SCHEMAS / f"{name}.json").read_text())
    return jsonschema_rs.validator_for(schema, validate_formats=True)


def schema_errors(name: str, message: Any) -> list[str]:
    return [f"{e.instance_path}: {e.message}" for e in validator(name).iter_errors(message)]


def now_iso() -> str:
    moment = dt.datetime.now(dt.UTC)
    return moment.strftime("%Y-%m-%dT%H:%M:%S.") + f"{moment.microsecond // 10_000:02d}Z"


class Vehicle:
    def __init__(
        self,
        interface: str,
        manufacturer: str,
        serial: str,
        position: tuple[float, float],
        actions: list[str],
        *,
        host: str = "127.0.0.1",
        port: int = 1883,
        speed: float = 5.0,
        action_time: float = 0.5,
        battery: float = 90.0,
        log: Path | None = None,
        ignore_orders: bool = False,
        keepalive: int = 2,
        state_interval: float = 1.0,
    ) -> None:
        self.base = f"{interface}/v2/{manufacturer}/{serial}"
        self.manufacturer, self.serial = manufacturer, serial
        self.x, self.y = position
        self.actions = actions
        self.speed, self.action_time, self.battery = speed, action_time, battery
        self.log = log
        self.ignore_orders = ignore_orders
        self.state_interval = state_interval  # seconds: a state this often, as its factsheet says
        self.lock = threading.RLock()
        self.received: list[dict[str, Any]] = []  # {"topic", "message", "errors"}
        self.headers: dict[str, int] = {}
        self.order_id = ""
        self.order_update_id = 0
        self.last_node_id = ""
        self.last_node_seq = 0
        self.nodes: list[dict[str, Any]] = []  # nodes not reached yet
        self.edges: list[dict[str, Any]] = []
        self.action_states: list[dict[str, Any]] = []
        self.running: list[tuple[str, float]] = []  # (actionId, ends at)
        self.queued: list[dict[str, Any]] = []  # HARD actions waiting their turn
        self.driving = False
        self.dropped = False
        self.did: list[str] = []  # actions finished
        self.stop = threading.Event()
        self.client = mqtt.Client(
            CallbackAPIVersion.VERSION2, client_id=f"vehicle-{serial}-{time.time_ns()}"
        )
        self.client.will_set(
            f"{self.base}/connection",
            json.dumps(self._connection("CONNECTIONBROKEN")),
            qos=1,
            retain=True,
        )
        self.client.on_message = self._on_message
        self.client.on_connect = self._on_connect
        self.client.connect(host, port, keepalive=keepalive)
        self.client.loop_start()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    # -- messages out ----------------------------------------------------------------

    def _header(self, topic: str) -> dict[str, Any]:
        n = self.headers.get(topic, 0)
        self.headers[topic] = n + 1
        return {"headerId": n, "timestamp": now_iso(), "version": VERSION,
                "manufacturer": self.manufacturer, "serialNumber": self.serial}  # fmt: skip

    def _connection(self, state: str) -> dict[str, Any]:
        return {**self._header("connection"), "connectionState": state}

    def _on_connect(self, client: mqtt.Client, *_: Any) -> None:
        client.subscribe(f"{self.base}/order", qos=0)
        client.subscribe(f"{self.base}/instantActions", qos=0)
        client.publish(
            f"{self.base}/connection", json.dumps(self._connection("ONLINE")), qos=1, retain=True
        )
        self.publish_state()

    def factsheet(self) -> dict[str, Any]:
        return {
            **self._header("factsheet"),
            "typeSpecification": {"seriesName": "test-agv", "agvKinematic": "DIFF",
                                  "agvClass": "CARRIER", "maxLoadMass": 100.0,
                                  "localizationTypes": ["NATURAL"],
                                  "navigationTypes": ["AUTONOMOUS"]},
            "physicalParameters": {"speedMin": 0.1, "speedMax": self.speed,
                                   "accelerationMax": 1.0, "decelerationMax": 1.0,
                                   "heightMax": 1.0, "width": 1.0, "length": 1.5},
            "protocolLimits": {"maxStringLens": {}, "maxArrayLens": {},
                               "timing": {"minOrderInterval": 0.1, "minStateInterval": 0.1,
                                          "defaultStateInterval": self.state_interval}},
            "protocolFeatures": {
                "optionalParameters": [],
                "agvActions": [
                    *({"actionType": a, "actionScopes": ["NODE"]} for a in self.actions),
                    {"actionType": "cancelOrder", "actionScopes": ["INSTANT"]},
                    {"actionType": "factsheetRequest", "actionScopes": ["INSTANT"]},
                ],
            },
            "agvGeometry": {},
            "loadSpecification": {},
        }  # fmt: skip

    def state(self) -> dict[str, Any]:
        with self.lock:
            return {
                **self._header("state"),
                "orderId": self.order_id,
                "orderUpdateId": self.order_update_id,
                "lastNodeId": self.last_node_id,
                "lastNodeSequenceId": self.last_node_seq,
                "nodeStates": [
                    {"nodeId": n["nodeId"], "sequenceId": n["sequenceId"],
                     "released": n["released"]} for n in self.nodes
                ],
                "edgeStates": [
                    {"edgeId": e["edgeId"], "sequenceId": e["sequenceId"],
                     "released": e["released"]} for e in self.edges
                ],
                "driving": self.driving,
                "actionStates": [dict(a) for a in self.action_states],
                "batteryState": {"batteryCharge": self.battery, "charging": False},
                "operatingMode": "AUTOMATIC",
                "errors": [],
                "safetyState": {"eStop": "NONE", "fieldViolation": False},
                "agvPosition": {"x": self.x, "y": self.y, "theta": 0.0, "mapId": "floor-1",
                                "positionInitialized": True},
            }  # fmt: skip

    def publish_state(self) -> None:
        if self.stop.is_set():
            return  # frozen, or leaving
        with self.lock:  # numbered and sent in one go: two threads publish, in order
            state = self.state()
            problems = schema_errors("state", state)
            assert not problems, problems  # the test vehicle itself keeps to the schema
            self.client.publish(f"{self.base}/state", json.dumps(state), qos=0)

    # -- messages in -------------------------------------------------------------------

    def _on_message(self, client: mqtt.Client, userdata: Any, msg: mqtt.MQTTMessage) -> None:
        message = json.loads(msg.payload)
        what = msg.topic.rsplit("/", 1)[1]
        errors = schema_errors(what, message)
        record = {"topic": msg.topic, "message": message, "errors": errors}
        with self.lock:
            self.received.append(record)
            self._write(record)
            if what == "order":
                if not self.ignore_orders:
                    self._take(message)
            else:
                for action in message.get("actions", []):
                    self._instant(action)
        self.publish_state()

    def _write(self, record: dict[str, Any]) -> None:
        if self.log is not None:
            with self.log.open("a") as out:
                out.write(json.dumps(record) + "\n")

    def _take(self, order: dict[str, Any]) -> None:
        self.order_id, self.order_update_id = order["orderId"], order["orderUpdateId"]
        nodes = sorted(order["nodes"], key=lambda n: n["sequenceId"])
        first = nodes[0]
        self.last_node_id, self.last_node_seq = first["nodeId"], first["sequenceId"]
        self.nodes = nodes[1:]
        self.edges = list(order["edges"])
        self.action_states = [
            {"actionId": a["actionId"], "actionType": a["actionType"], "actionStatus": "WAITING"}
            for node in nodes for a in node["actions"]
        ]  # fmt: skip
        self.running, self.queued = [], []
        self.driving = bool(self.nodes)

    def _instant(self, action: dict[str, Any]) -> None:
        kind = action["actionType"]
        if kind == "factsheetRequest":
            self.client.publish(f"{self.base}/factsheet", json.dumps(self.factsheet()), qos=0)
        elif kind == "cancelOrder":
            for state in self.action_states:
                if state["actionStatus"] != "FINISHED":
                    state["actionStatus"] = "FAILED"
            self.nodes, self.edges, self.running, self.queued = [], [], [], []
            self.driving = False
        self.action_states.append(
            {"actionId": action["actionId"], "actionType": kind, "actionStatus": "FINISHED"}
        )

    # -- driving and working -------------------------------------------------------------

    def _run(self) -> None:
        last_state = 0.0
        step = 0.05
        while not self.stop.wait(step):
            with self.lock:
                changed = self._advance(step)
            if changed or time.monotonic() - last_state >= self.state_interval:
                self.publish_state()
                last_state = time.monotonic()

    def _advance(self, dt_: float) -> bool:
        now = time.monotonic()
        changed = False
        for action_id, ends in list(self.running):
            if now >= ends:
                self.running.remove((action_id, ends))
                self._status(action_id, "FINISHED")
                self.did.append(action_id)
                self._write({"did": action_id})
                changed = True
        if not self.running and self.queued:
            action = self.queued.pop(0)
            self._start(action, now)
            changed = True
        if self.running or self.queued or not self.nodes:
            return changed
        target = self.nodes[0]
        tx, ty = target["nodePosition"]["x"], target["nodePosition"]["y"]
        left = math.dist((self.x, self.y), (tx, ty))
        move = self.speed * dt_
        if left > move:
            self.x += (tx - self.x) * move / left
            self.y += (ty - self.y) * move / left
            return changed
        self.x, self.y = tx, ty
        self.nodes.pop(0)
        self.edges = [e for e in self.edges if e["endNodeId"] != target["nodeId"]]
        self.last_node_id, self.last_node_seq = target["nodeId"], target["sequenceId"]
        self.driving = bool(self.nodes)
        for action in target["actions"]:
            if action["blockingType"] == "HARD":
                self.queued.append(action)
            else:
                self._start(action, now)
        return True

    def _start(self, action: dict[str, Any], now: float) -> None:
        self.running.append((action["actionId"], now + self.action_time))
        self._status(action["actionId"], "RUNNING")

    def _status(self, action_id: str, status: str) -> None:
        for state in self.action_states:
            if state["actionId"] == action_id:
                state["actionStatus"] = status

    def freeze(self) -> None:
        """Stop publishing, connection kept (MQTT keep-alive goes on): no last will."""
        self.stop.set()
        self.thread.join(5)

    def drop(self) -> None:
        """Lose the connection without a word: the broker publishes the last will."""
        self.stop.set()
        self.thread.join(5)
        self.client.loop_stop()  # no reconnect
        sock = self.client.socket()
        if sock is not None:
            sock.close()
        self.dropped = True

    def close(self) -> None:
        """Leave in an orderly way: OFFLINE, as the specification asks."""
        if self.dropped:
            return
        self.stop.set()
        self.thread.join(5)
        self.client.publish(
            f"{self.base}/connection", json.dumps(self._connection("OFFLINE")), qos=1, retain=True
        ).wait_for_publish(5)
        self.client.disconnect()
        self.client.loop_stop()


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--interface", required=True)
    parser.add_argument("--manufacturer", default="acme")
    parser.add_argument("--serial", required=True)
    parser.add_argument("--x", type=float, default=0.0)
    parser.add_argument("--y", type=float, default=0.0)
    parser.add_argument("--actions", default="pick")
    parser.add_argument("--speed", type=float, default=5.0)
    parser.add_argument("--action-time", type=float, default=0.5)
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=1883)
    parser.add_argument("--log", type=Path)
    parser.add_argument("--ignore-orders", action="store_true")
    parser.add_argument("--keepalive", type=int, default=2, help="MQTT keep-alive, seconds")
    args = parser.parse_args()
    vehicle = Vehicle(
        args.interface, args.manufacturer, args.serial, (args.x, args.y),
        args.actions.split(","), host=args.host, port=args.port, speed=args.speed,
        action_time=args.action_time, log=args.log, ignore_orders=args.ignore_orders,
        keepalive=args.keepalive,
    )  # fmt: skip
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with contextlib.suppress(KeyboardInterrupt):
        stop.wait()
    vehicle.close()


if __name__ == "__main__":
    main()
