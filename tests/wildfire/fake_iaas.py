"""IaaSs answering like ``robocloud iaas`` does, in memory, behind one httpx.MockTransport.

Each fake is reached by its host (``http://cloud-a.test``); a test can make
one refuse connections (``down``), leave its sends unanswered as if the
client's timeout ran out (``hang_sends``: its POSTs alone, so its health
still answers and the background health check never moves sends away from
it), or answer anything (``answer``). Requests keep their
Idempotency-Key, as the real store does. Missions (``/v1/missions``) are
planned by ``fake_missions.plan`` over the fake's robots; a test moves them on
(``fake_missions.advance``, ``replan``) and calls ``changed()``, which wakes
the event streams of ``served_iaas.py``.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from typing import Any

import httpx
from fake_missions import FINAL, plan

KEY = "s3cret-key"
START = datetime(2026, 1, 1, tzinfo=UTC)


def robot(robot_id: str, cloud: str, status: str = "idle", caps: tuple[str, ...] = ("grabber",),
          position: tuple[float, float] = (100.0, 200.0), battery: float = 80.0,
          seen_ago: float | None = 0.1) -> dict[str, Any]:
    return {"id": robot_id, "cloud": cloud, "kind": "tribot", "position": list(position),
            "speed": 1.0, "battery": battery, "status": status, "capabilities": list(caps),
            "capability_kinds": {}, "request": None, "progress": None, "seen_ago": seen_ago}


class FakeIaas:
    def __init__(self, cloud: str, robots: list[dict[str, Any]] | None = None) -> None:
        self.cloud = cloud
        self.robots = robots or []
        self.requests: dict[str, dict[str, Any]] = {}
        self.keys: dict[str, str] = {}
        self.calls: list[httpx.Request] = []
        self.answer: Callable[[httpx.Request], httpx.Response] | None = None
        self.answer_only: str | None = None  # a method: ``answer`` for it alone
        self.down = False
        self.hang_sends = False  # a POST gets no answer; every other call does
        self.listing: list[dict[str, Any]] | None = None  # GET /v1/clouds
        self.robots_page: int | None = None  # GET /v1/robots in pages of this many (Link)
        self.clock = START
        self.spec: dict[str, Any] | None = None  # GET /openapi.json (404 while None)
        self.missions: dict[str, dict[str, Any]] = {}
        self.mission_keys: dict[str, tuple[str, bytes]] = {}
        self.lock = threading.Condition()  # held by each call; notified by ``changed``
        self.version = 0  # of the missions, + 1 at each change
        self.offers_missions = True  # False: an IaaS older than missions (404)

    def changed(self) -> None:
        """A test changed a mission: the event streams send it."""
        with self.lock:
            self.version += 1
            self.lock.notify_all()

    @property
    def url(self) -> str:
        return f"http://{self.cloud}.test"

    def add(self, label: str | None = None, state: str = "received", **task: Any
            ) -> dict[str, Any]:
        self.clock += timedelta(seconds=1)
        at = self.clock.isoformat().replace("+00:00", "Z")
        request_id = f"req-{self.cloud[-1]}{len(self.requests):04d}"
        record = {"id": request_id, "label": label, "state": state, "reason": None,
                  "created_at": at, "updated_at": at,
                  "task": {"location": [1.0, 2.0], "actuating": {"grabber": 1}, **task},
                  "coalition": None, "time": None, "cost": None, "pareto": [],
                  "optimizer": None, "selection_ms": None,
                  "history": [{"kind": "state", "state": state, "at": at, "detail": None}]}
        self.requests[request_id] = record
        return record

    def __call__(self, request: httpx.Request) -> httpx.Response:
        self.calls.append(request)
        if self.down:
            raise httpx.ConnectError("Connection refused", request=request)
        if self.hang_sends and request.method == "POST":
            raise httpx.ReadTimeout("timed out", request=request)
        if self.answer is not None and self.answer_only in (None, request.method):
            return self.answer(request)
        path, method = request.url.path, request.method
        if path == "/healthz":
            return httpx.Response(200, json={"status": "ok", "cloud": self.cloud,
                                             "robots": len(self.robots), "store": "sqlite",
                                             "time_scale": 10.0})
        if path == "/openapi.json":  # open, as the real IaaS has it
            if self.spec is None:
                return httpx.Response(404, json={"detail": "there is no such path."})
            return httpx.Response(200, json=self.spec)
        if request.headers.get("authorization") != f"Bearer {KEY}":
            return httpx.Response(401, json={"detail": "the API key is not valid."})
        if path == "/v1/robots":
            return self.robot_page(request)
        if path == "/v1/clouds":
            listing = self.listing if self.listing is not None else [
                {"cloud": self.cloud, "robots": len(self.robots), "idle": 0, "offline": 0}]
            return httpx.Response(200, json=listing)
        if path == "/v1/requests" and method == "GET":
            return self.list(request)
        if path == "/v1/requests" and method == "POST":
            return self.create(request)
        if path.startswith("/v1/missions") and not self.offers_missions:
            return httpx.Response(404, json={"detail": "there is no such path."})
        if path.startswith("/v1/missions"):
            with self.lock:
                return self.mission_call(request)
        parts = path.split("/")
        if len(parts) >= 4 and parts[3] in self.requests:
            record = self.requests[parts[3]]
            if parts[-1] == "cancel":
                record["state"] = "canceled"
            return httpx.Response(200, json=record)
        return httpx.Response(404, json={"detail": f"there is no request {parts[-1]!r}."})

    def robot_page(self, request: httpx.Request) -> httpx.Response:
        """The robots, in pages with a ``Link`` to the next one when ``robots_page`` is set."""
        if self.robots_page is None:
            return httpx.Response(200, json=self.robots)
        params = request.url.params
        start = int(params.get("cursor", "0"))
        size = min(self.robots_page, int(params.get("limit", "1000")))
        headers = {}
        if start + size < len(self.robots):
            query = httpx.QueryParams(params).set("cursor", str(start + size))
            headers["Link"] = f'</v1/robots?{query}>; rel="next"'
        return httpx.Response(200, json=self.robots[start:start + size], headers=headers)

    def list(self, request: httpx.Request) -> httpx.Response:
        params = request.url.params
        items = sorted(self.requests.values(), key=lambda r: (r["created_at"], r["id"]),
                       reverse=True)
        if params.get("state"):
            items = [r for r in items if r["state"] == params["state"]]
        if params.get("before"):
            if params["before"] not in self.requests:
                return httpx.Response(422, json={"detail": "before: no such request."})
            edge = self.requests[params["before"]]
            items = [r for r in items
                     if (r["created_at"], r["id"]) < (edge["created_at"], edge["id"])]
        limit = int(params.get("limit", 50))
        page = items[:limit]
        return httpx.Response(200, json={"items": page,
                                         "next": page[-1]["id"] if len(items) > limit else None})

    def create(self, request: httpx.Request) -> httpx.Response:
        key = request.headers.get("idempotency-key")
        if key and key in self.keys:
            return httpx.Response(202, json=self.requests[self.keys[key]])
        task = json.loads(request.content)
        record = self.add(task.pop("label", None), **task)
        if key:
            self.keys[key] = record["id"]
        return httpx.Response(202, json=record)


    def mission_call(self, request: httpx.Request) -> httpx.Response:
        parts = request.url.path.split("/")[3:]
        if not parts and request.method == "POST":
            return self.create_mission(request)
        if not parts:
            items = sorted(self.missions.values(), key=lambda m: m["created_at"], reverse=True)
            state = request.url.params.get("state")
            return httpx.Response(200, json={
                "missions": [m for m in items if not state or m["state"] == state],
                "next": None})
        mission = self.missions.get(parts[0])
        if mission is None:
            return httpx.Response(404, json={"detail": f"there is no mission {parts[0]!r}."})
        if request.method == "DELETE" and mission["state"] not in FINAL:
            mission["state"] = "canceled"
            for task in (mission["plan"] or {}).get("tasks", []):
                if task["state"] != "done":
                    task["state"] = "canceled"
            for route in (mission["plan"] or {}).get("robots", []):
                route["state"] = "released"
            mission["history"].append({"at": time.time(), "state": "canceled",
                                       "note": "canceled by the user"})
            self.version += 1
            self.lock.notify_all()
        return httpx.Response(200, json=mission)

    def create_mission(self, request: httpx.Request) -> httpx.Response:
        key = request.headers.get("idempotency-key")
        if key and key in self.mission_keys:
            known, body = self.mission_keys[key]
            if body != request.content:
                return httpx.Response(422, json={"detail": "the Idempotency-Key header was "
                                                           "given before with another mission."})
            return httpx.Response(202, json=self.missions[known])
        body = json.loads(request.content)
        if not isinstance(body.get("tasks"), list) or not body["tasks"]:
            return httpx.Response(422, json={"detail": "tasks: a mission needs 1 to 100 tasks."})
        now = time.time()
        mission_id = f"mis-{self.cloud[-1]}{len(self.missions):04d}"
        label = body.pop("label", None)
        body.pop("time_limit", None)
        mission: dict[str, Any] = {
            "id": mission_id, "label": label, "state": "underway", "reason": None,
            "created_at": now, "updated_at": now, "started_at": now, "mission": body,
            "plan": None, "progress": 0.0,
            "history": [{"at": now, "state": "planning", "note": "received"}]}
        try:
            mission["plan"] = plan(body, self.robots)
            mission["history"].append({"at": now, "state": "underway", "note": "planned"})
        except ValueError as error:
            mission["state"], mission["reason"] = "rejected", f"{error}."
            mission["history"].append({"at": now, "state": "rejected", "note": str(error)})
        self.missions[mission_id] = mission
        if key:
            self.mission_keys[key] = (mission_id, request.content)
        return httpx.Response(202, json=mission,
                              headers={"Location": f"/v1/missions/{mission_id}"})


class FakeFederation:
    """Several fake IaaSs behind one transport, each at its own host."""

    def __init__(self, *clouds: FakeIaas) -> None:
        self.clouds = {c.cloud: c for c in clouds}

    def __call__(self, request: httpx.Request) -> httpx.Response:
        cloud = request.url.host.removesuffix(".test")
        return self.clouds[cloud](request)

    def transport(self) -> httpx.MockTransport:
        return httpx.MockTransport(self)
