"""A minimal robocloud robot, zenoh and json only: docs/protocol.md in about 100 lines.

    python examples/example_robot.py --connect tcp/127.0.0.1:7447 --cloud cloud-a --id ex-1
    robocloud robot-check --connect tcp/127.0.0.1:7447 --cloud cloud-a --robot ex-1

It drives straight to a task's location at SPEED and works there for its
capabilities' time; the battery stays full (a real robot reports its own).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import threading
import time
from typing import Any

import zenoh

CAPABILITIES: dict[str, dict[str, Any]] = {
    "grabber": {"kind": "actuating", "time": 1.0, "cost": 1.0}
}
SPEED = 2.0  # m/s


class Robot:
    def __init__(self, session: zenoh.Session, cloud: str, robot_id: str, x: float = 0.0) -> None:
        self.cloud, self.id, self.position = cloud, robot_id, (x, 0.0)
        self.task: dict[str, Any] | None = None  # request_id, phase, progress, capabilities
        self.last_task: dict[str, Any] | None = None  # kept until the next task
        self.job: dict[str, Any] = {}
        self.seq, self.lock = 0, threading.RLock()
        prefix = f"robocloud/{cloud}/robots/{robot_id}"
        self.publisher = session.declare_publisher(f"{prefix}/state")
        self.queryable = session.declare_queryable(f"{prefix}/cmd", self.on_command)
        # The IaaS says here why it refused a state (a field missing, out of range).
        self.errors = session.declare_subscriber(f"{prefix}/error", self.on_error)

    def on_error(self, sample: zenoh.Sample) -> None:
        print("the IaaS refused a state:", json.loads(sample.payload.to_bytes())["error"])

    def on_command(self, query: zenoh.Query) -> None:
        try:
            command = json.loads(query.payload.to_bytes() if query.payload else b"")
        except ValueError:
            command = {}
        with self.lock:
            ok, error = self.obey(command)
            answer = {"ok": ok, "robot": self.id, "request_id": command.get("request_id"),
                      "error": error}  # fmt: skip
            query.reply(query.key_expr, json.dumps(answer))
            self.publish()  # a state on every change

    def obey(self, command: dict[str, Any]) -> tuple[bool, str | None]:
        request = command.get("request_id")
        current = self.task["request_id"] if self.task else None
        if command.get("type") == "cancel":
            if current not in (None, request):
                return False, f"robot {self.id} is on request {current}, not {request}."
            self.task = None  # stop where it is
            return True, None
        if command.get("type") != "assign":
            return False, f"robot {self.id} does not know the command {command.get('type')!r}."
        if current == request:
            return True, None  # a repeated assign: already on it
        if current is not None:
            return False, f"robot {self.id} is busy with request {current}."
        names = command.get("capabilities", [])
        if not names or any(name not in CAPABILITIES for name in names):
            return False, f"robot {self.id} has only the capabilities {', '.join(CAPABILITIES)}."
        target = command.get("location")
        if not (isinstance(target, list) and len(target) == 2
                and all(isinstance(v, (int, float)) for v in target)):  # fmt: skip
            return False, f"robot {self.id} needs a location [x, y] to go to."
        times = [CAPABILITIES[name]["time"] for name in names]
        self.job = {"start": time.monotonic(), "from": self.position, "to": tuple(target),
                    "travel": math.dist(self.position, tuple(target)) / SPEED,
                    "work": sum(times) if command.get("execution") == "sequential" else max(times)}
        self.task = {"request_id": request, "phase": "travel", "progress": 0.0,
                     "capabilities": names}  # fmt: skip
        return True, None

    def step(self) -> bool:
        """Move the task on; whether its phase changed."""
        if self.task is None:
            return False
        job, elapsed = self.job, time.monotonic() - self.job["start"]
        f = min(1.0, elapsed / job["travel"]) if job["travel"] else 1.0
        (x0, y0), (x1, y1) = job["from"], job["to"]
        self.position = (x0 + (x1 - x0) * f, y0 + (y1 - y0) * f)
        total = job["travel"] + job["work"]
        phase = "travel" if elapsed < job["travel"] else "work"
        if elapsed >= total:  # done: idle at the location, the task kept in last_task
            self.last_task = {**self.task, "phase": "done", "progress": 1.0}
            self.task = None
            return True
        changed: bool = phase != self.task["phase"]
        self.task.update(phase=phase, progress=min(1.0, elapsed / total))
        return changed

    def state(self) -> dict[str, Any]:
        self.seq += 1
        return {"id": self.id, "cloud": self.cloud, "kind": "example", "speed": SPEED,
                "position": list(self.position), "battery": 100.0,
                "status": "busy" if self.task else "idle", "travel_cost_per_m": 0.01,
                "capabilities": CAPABILITIES, "task": self.task, "last_task": self.last_task,
                "seq": self.seq, "sent_at": time.time()}  # fmt: skip

    def publish(self) -> None:
        self.publisher.put(json.dumps(self.state()))

    def run(self, stop: threading.Event) -> None:
        last = 0.0
        while not stop.wait(0.1):
            with self.lock:
                if self.step() or time.monotonic() - last >= 0.5:  # at least once a second
                    self.publish()
                    last = time.monotonic()


def main() -> None:
    parser = argparse.ArgumentParser(description="A minimal robocloud robot.")
    parser.add_argument("--connect", default="tcp/127.0.0.1:7447", help="the IaaS's router")
    parser.add_argument("--cloud", default="cloud-a")
    parser.add_argument("--id", default="ex-1")
    parser.add_argument("--x", type=float, default=0.0, help="where it starts, metres")
    args = parser.parse_args()
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps([args.connect]))
    config.insert_json5("connect/timeout_ms", "-1")  # start before the IaaS: wait for it
    config.insert_json5("connect/retry", "{period_init_ms: 500, period_max_ms: 1000}")
    with zenoh.open(config) as session, contextlib.suppress(KeyboardInterrupt):  # Ctrl-C stops
        Robot(session, args.cloud, args.id, args.x).run(threading.Event())


if __name__ == "__main__":
    main()
