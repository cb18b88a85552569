"""A robot written from the README's "Robots on the wire" alone: zenoh and json, no robocloud.

It joins a cloud's router as a Zenoh client, publishes its state twice a
second and on every change, answers commands on its cmd key, drives straight
to a task's location and works there, and keeps its last finished task in
``last_task``. Faults for the tests: ``ack_delay`` (it takes a command but
answers late), ``silent()`` / ``back()`` (no states and no answers, as a
crashed robot; it comes back still holding its task), ``never_arrives`` (it
drives in circles: its progress creeps towards one half and never gets there).
Closed, it publishes a last state, ``offline``, as a robot that shuts down.
"""

from __future__ import annotations

import json
import math
import threading
import time
from typing import Any

import zenoh


class ReadmeRobot:
    def __init__(
        self,
        cloud: str,
        robot_id: str,
        endpoint: str,
        position: tuple[float, float],
        capabilities: dict[str, dict[str, Any]],
        speed: float = 10.0,
        ack_delay: float = 0.0,
        never_arrives: bool = False,
        keep_done: float = 3.0,
    ) -> None:
        self.cloud, self.id = cloud, robot_id
        self.position = position
        self.capabilities = capabilities
        self.speed = speed
        self.ack_delay = ack_delay
        self.never_arrives = never_arrives
        self.keep_done = keep_done  # seconds a finished task stays in the state
        self.task: dict[str, Any] | None = None  # request_id, phase, progress, capabilities
        self.last_task: dict[str, Any] | None = None
        self.job: dict[str, Any] | None = None  # target, travel and work seconds, started
        self.commands: list[tuple[float, dict[str, Any]]] = []  # (when, command) received
        self.states: list[dict[str, Any]] = []  # every state it published
        self.seq = 0
        self.done_at = 0.0
        self.is_silent = False
        self.shutting_down = False  # its last state says offline: it cannot work any more
        self._lock = threading.RLock()
        config = zenoh.Config()
        config.insert_json5("mode", '"client"')
        config.insert_json5("connect/endpoints", json.dumps([endpoint]))
        config.insert_json5("scouting/multicast/enabled", "false")
        # Its router restarted (the IaaS killed and started again): back within half a
        # second, where Zenoh's default waits 1 s, then up to 4 s, between attempts.
        config.insert_json5(
            "connect/retry",
            json.dumps({"period_init_ms": 100, "period_max_ms": 500, "period_increase_factor": 2}),
        )
        self.session = zenoh.open(config)
        prefix = f"robocloud/{cloud}/robots/{robot_id}"
        self.publisher = self.session.declare_publisher(f"{prefix}/state")
        self.queryable = self.session.declare_queryable(f"{prefix}/cmd", self._on_command)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    # -- faults --------------------------------------------------------------------

    def silent(self) -> None:
        self.is_silent = True

    def back(self) -> None:
        self.is_silent = False
        self.publish()

    def close(self) -> None:
        """Shut down; a robot still talking says so first: its last state is ``offline``."""
        self._stop.set()
        self._thread.join(5)
        self.shutting_down = True
        self.publish()
        self.queryable.undeclare()
        self.publisher.undeclare()
        self.session.close()

    # -- what a robot does -----------------------------------------------------------

    def _on_command(self, query: zenoh.Query) -> None:
        command = json.loads(query.payload.to_bytes()) if query.payload is not None else {}
        with self._lock:
            self.commands.append((time.monotonic(), command))
        if self.is_silent:
            return  # a crashed robot answers nothing
        if command.get("type") == "assign" and self.ack_delay:
            time.sleep(self.ack_delay)  # it takes the task, but answers late
        with self._lock:
            ok, error = self._obey(command)
        answer = {
            "ok": ok,
            "robot": self.id,
            "request_id": command.get("request_id"),
            "error": error,
        }
        query.reply(query.key_expr, json.dumps(answer))
        self.publish()

    def _obey(self, command: dict[str, Any]) -> tuple[bool, str | None]:
        request = command.get("request_id")
        current = (
            self.task["request_id"]
            if self.task and self.task["phase"] in ("travel", "work")
            else None
        )
        if command.get("type") == "assign":
            if current == request:
                return True, None
            if current is not None:
                return False, f"robot {self.id} is busy with request {current}."
            target = command["location"]
            work = [self.capabilities[c]["time"] for c in command["capabilities"]]
            self.job = {
                "target": target,
                "from": self.position,
                "travel": math.dist(self.position, target) / self.speed,
                "work": max(work) if command.get("execution") != "sequential" else sum(work),
                "started": time.monotonic(),
            }
            self.task = {
                "request_id": request,
                "phase": "travel",
                "progress": 0.0,
                "capabilities": command["capabilities"],
            }
            self.last_task = None
            return True, None
        if command.get("type") == "cancel":
            if current not in (None, request):
                return False, f"robot {self.id} is not on request {request}."
            self.job, self.task = None, None
            return True, None
        return False, "unknown command"

    def _advance(self) -> None:
        with self._lock:
            job, task = self.job, self.task
            if job is None or task is None:
                return
            elapsed = time.monotonic() - job["started"]
            if self.never_arrives:  # lost: it reports progress, and never arrives
                task["progress"] = 0.5 * elapsed / (elapsed + 1.0)
                return
            total = job["travel"] + job["work"]
            f = min(1.0, elapsed / job["travel"]) if job["travel"] else 1.0
            (x0, y0), (x1, y1) = job["from"], job["target"]
            self.position = (x0 + (x1 - x0) * f, y0 + (y1 - y0) * f)
            task["progress"] = min(1.0, elapsed / total) if total else 1.0
            task["phase"] = "travel" if elapsed < job["travel"] else "work"
            if elapsed >= total:
                task["phase"], task["progress"] = "done", 1.0
                self.last_task, self.job = dict(task), None
                self.done_at = time.monotonic()

    def state(self) -> dict[str, Any]:
        with self._lock:
            self.seq += 1
            busy = self.task is not None and self.task["phase"] in ("travel", "work")
            status = "offline" if self.shutting_down else "busy" if busy else "idle"
            return {
                "id": self.id,
                "cloud": self.cloud,
                "kind": "readme-robot",
                "position": list(self.position),
                "speed": self.speed,
                "battery": 90.0,
                "status": status,
                "travel_cost_per_m": 0.01,
                "capabilities": self.capabilities,
                "task": dict(self.task) if self.task else None,
                "last_task": self.last_task,
                "seq": self.seq,
                "sent_at": time.time(),
            }

    def publish(self) -> None:
        if self.is_silent:
            return
        state = self.state()
        with self._lock:
            self.states.append(state)
        self.publisher.put(json.dumps(state))

    def _run(self) -> None:
        self.publish()  # heard at once, not half a second after it joined
        while not self._stop.wait(0.5):
            self._advance()
            self.publish()
            with self._lock:
                # A finished task stays in the state for a few seconds, then only in last_task.
                finished = self.task is not None and self.task["phase"] == "done"
                if finished and time.monotonic() - self.done_at > self.keep_done:
                    self.task = None

    def commands_for(self, request_id: str, kind: str) -> list[float]:
        with self._lock:
            return [
                at
                for at, c in self.commands
                if c.get("type") == kind and c.get("request_id") == request_id
            ]
