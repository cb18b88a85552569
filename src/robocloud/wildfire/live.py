"""What the page shows live, kept by the wildfire server: no I/O, fed by ``feed.py``.

Why one long file: ``LiveModel`` is one object whose every step (ingest,
publish, snapshot) keeps the same tables of robots, clouds, requests and
alerts consistent with each other; the helpers below it serve it alone.

The model holds the fleet as last heard (every robot with the wall time it
last reported), the clouds and their health, the requests being followed and
the alerts they raised. ``publish()`` turns what changed since the previous
call into one *delta*; ``snapshot()`` is everything as last published. A page
gets a snapshot, then every delta: at 1,000 robots a delta is a few hundred
small changes, where the whole fleet is about 300 KB of JSON.

Freshness is explicit: a robot not heard from for ``stale_after`` seconds, or
whose cloud is down, carries ``heard`` (the wall time it last reported) and the
page greys it with its age; a fresh robot's ``heard`` is null, so the age of a
healthy fleet costs nothing to send.

Alerts (each with an id, a time, a level and a sentence): a cloud down or
back, a robot of a followed request failed or replaced, a request failed or
rejected. Only what happens after the server started is alerted.
"""

from __future__ import annotations

import json
import logging
import re
import zlib
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from robocloud.domain.request import FINAL_STATES, REQUEST_STATES
from robocloud.wildfire.config import WildfireSettings
from robocloud.wildfire.fleet_view import capability_kinds

log = logging.getLogger(__name__)
# How each alert level is logged: the operator's log says what the page says.
LOG_LEVELS = {"danger": logging.WARNING, "warning": logging.WARNING, "info": logging.INFO,
              "ok": logging.INFO}
CONTROL = re.compile(r"[\x00-\x1f\x7f]")

ROBOT_COLUMNS = (
    "id", "cloud", "status", "x", "y", "battery", "capabilities", "request", "phase",
    "progress", "heard",
)
COLUMN = {name: i for i, name in enumerate(ROBOT_COLUMNS)}
STATUSES = ("idle", "reserved", "busy", "charging", "offline")
# Colour-blind-safe colours (Okabe-Ito, then Tol). A cloud's colour comes from
# its name (CRC-32), the next free one on a clash: the same on every page and
# every load, whichever robot is heard first.
CLOUD_COLOURS = (
    "#0072B2", "#56B4E9", "#009E73", "#882255", "#CC79A7", "#8C6D1F", "#6A3D9A", "#117733",
)
# A robot not heard from for this long is forgotten (its cloud stays listed).
FORGET_AFTER = 900.0
MAX_ROBOTS = 100_000
MAX_CLOUDS = 64
MAX_NAME = 64
MAX_TEXT = 500
MAX_ALERTS = 200
ALERTS_IN_SNAPSHOT = 50
MAX_FOLLOWED = 300
REQUESTS_IN_SNAPSHOT = 100
# A cloud first seen this long after the start joined; before, it was simply there.
STARTUP_GRACE = 10.0
ROBOT_EVENT = re.compile(r"^robot \S+ (failed|replaced by)\b")


def cloud_colour(name: str, taken: set[str]) -> str:
    first = zlib.crc32(name.encode()) % len(CLOUD_COLOURS)
    for step in range(len(CLOUD_COLOURS)):
        colour = CLOUD_COLOURS[(first + step) % len(CLOUD_COLOURS)]
        if colour not in taken:
            return colour
    return CLOUD_COLOURS[first]


def fmt_duration(seconds: float) -> str:
    """The page's one duration format (js/util.js ``fmtDuration``)."""
    if seconds < 1:
        return "under 1 s"
    if seconds < 60:
        return f"{round(seconds)} s"
    if seconds < 3600:
        minutes, rest = divmod(round(seconds), 60)
        return f"{minutes} min {rest:02d} s"
    hours, rest = divmod(round(seconds / 60), 60)
    return f"{hours} h {rest:02d} min"


def _number(value: Any, default: float | None = None) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return default
    return float(value)


def _name(value: Any, longest: int = MAX_NAME) -> bool:
    """An id or a name as the page can show it: a short text (a longer one is a lie)."""
    return isinstance(value, str) and 0 < len(value) <= longest


def _text(value: Any) -> str | None:
    return value[:MAX_TEXT] if isinstance(value, str) else None


def _when(text: Any) -> float | None:
    try:
        when = datetime.fromisoformat(str(text))
    except ValueError:
        return None
    return (when if when.tzinfo else when.replace(tzinfo=UTC)).timestamp()


@dataclass
class Alert:
    id: int
    at: float
    level: str  # "danger", "warning", "info" or "ok"
    kind: str  # "cloud", "robot", "request", "iaas"
    text: str
    cloud: str | None = None
    request: str | None = None

    def as_json(self) -> dict[str, Any]:
        return {"id": self.id, "at": round(self.at, 3), "level": self.level, "kind": self.kind,
                "text": self.text, "cloud": self.cloud, "request": self.request}


@dataclass
class Robot:
    row: list[Any]  # ROBOT_COLUMNS but ``heard``
    heard: float  # wall time of its last report
    kinds: dict[str, str] = field(default_factory=dict)


@dataclass
class Cloud:
    name: str
    colour: str
    status: str = "unknown"  # "up", "down" or "unknown"
    since: float = 0.0
    reason: str | None = None
    counts: dict[str, int] = field(default_factory=dict)
    iaas: str | None = None
    ever_up: bool = False  # its first "up" is not news, unless it joins later


@dataclass
class Followed:
    summary: dict[str, Any]
    endpoint_cloud: str | None
    seen_history: int = 0
    checked: float = 0.0


class LiveModel:
    def __init__(self, settings: WildfireSettings, started: float) -> None:
        self.settings = settings
        self.started = started
        self.robots: dict[str, Robot] = {}
        self.clouds: dict[str, Cloud] = {}
        self.listing: dict[str, dict[str, int]] | None = None  # live clouds, as last listed
        self.listing_at = 0.0
        self.fleet_at = 0.0
        self.endpoints: list[dict[str, Any]] = []
        self.time_scale: float | None = None
        self.limits: dict[str, dict[str, float]] | None = None  # the task's, from the IaaS's schema
        self.alerts: deque[Alert] = deque(maxlen=MAX_ALERTS)
        self.requests: dict[str, Followed] = {}
        self._next_alert = 1
        # What pages were last told: the base of the next delta and of snapshots.
        self._published_robots: dict[str, list[Any]] = {}
        self._published: dict[str, Any] = {}
        self._new_alerts: list[Alert] = []
        self._changed_requests: set[str] = set()
        self._endpoint_ok: dict[str, bool | None] = {}
        self._any_answering: bool | None = None

    # --- what comes in ---------------------------------------------------------
    def ingest_fleet(self, robots: Iterable[Any], at: float) -> None:
        """The robots an IaaS listed at ``at`` (``GET /v1/robots?scope=federation``)."""
        for data in robots:
            robot = _robot_row(data)
            if robot is None:
                continue
            row, kinds = robot
            if row[1] not in self.clouds and len(self.clouds) >= MAX_CLOUDS:
                continue
            seen_ago = _number(data.get("seen_ago"), 0.0) or 0.0
            heard = at - max(0.0, seen_ago)
            known = self.robots.get(row[0])
            if known is None:
                if len(self.robots) >= MAX_ROBOTS:
                    continue
                self.robots[row[0]] = Robot(row, heard, kinds)
            else:
                known.row, known.heard, known.kinds = row, max(known.heard, heard), kinds
            self._cloud(row[1])
        self.fleet_at = at

    def ingest_clouds(self, clouds: Iterable[Any], at: float) -> None:
        """The live clouds of the federation (``GET /v1/clouds``)."""
        listing: dict[str, dict[str, int]] = {}
        for info in clouds:
            if not isinstance(info, Mapping) or not _name(info.get("cloud")):
                continue
            if info["cloud"] not in self.clouds and len(self.clouds) >= MAX_CLOUDS:
                continue
            self._cloud(info["cloud"])
            listing[info["cloud"]] = {
                k: int(v) for k in ("robots", "idle", "offline")
                if isinstance(v := info.get(k), int) and not isinstance(v, bool)
            }
        self.listing = listing
        self.listing_at = at

    def ingest_endpoints(self, endpoints: Sequence[Mapping[str, Any]], time_scale: float | None
                         ) -> None:
        self.endpoints = [dict(e) for e in endpoints]
        self.time_scale = time_scale
        for endpoint in endpoints:
            if isinstance(endpoint.get("cloud"), str):
                self._cloud(endpoint["cloud"]).iaas = str(endpoint["url"])

    def ingest_request(self, record: Mapping[str, Any], cloud: str | None, at: float) -> None:
        """A request as its IaaS gives it: follow it, and alert what happened to it."""
        summary = request_summary(record, cloud)
        if summary is None:
            return
        request_id = summary["id"]
        followed = self.requests.get(request_id)
        if followed is None:
            followed = Followed(summary, cloud)
            self.requests[request_id] = followed
            self._changed_requests.add(request_id)
            self._evict_requests()
        elif followed.summary != summary:
            if summary["state"] != followed.summary["state"] and summary["state"] not in (
                "failed", "rejected"  # those are alerts, logged as such
            ):
                log.info("%s is %s.", one_line(_request_name(summary)), summary["state"])
            followed.summary = summary
            self._changed_requests.add(request_id)
        followed.checked = at
        history = record.get("history")
        if isinstance(history, list):
            for entry in history[followed.seen_history:]:
                if isinstance(entry, Mapping):
                    self._alert_history(summary, entry)
            followed.seen_history = max(followed.seen_history, len(history))

    def active_requests(self) -> list[tuple[str, str | None, float]]:
        """(id, the cloud holding it, when it was last read) of every unfinished request."""
        return [(i, f.endpoint_cloud, f.checked) for i, f in self.requests.items()
                if f.summary["state"] not in FINAL_STATES]

    def alert(self, level: str, kind: str, text: str, at: float, *, cloud: str | None = None,
              request: str | None = None) -> Alert:
        alert = Alert(self._next_alert, at, level, kind, humanize(text), cloud, request)
        log.log(LOG_LEVELS.get(level, logging.INFO), "%s", one_line(alert.text))
        self._next_alert += 1
        self.alerts.append(alert)
        self._new_alerts.append(alert)
        return alert

    # --- clouds ------------------------------------------------------------------
    def _cloud(self, name: str) -> Cloud:
        cloud = self.clouds.get(name)
        if cloud is None:
            cloud = Cloud(name, cloud_colour(name, {c.colour for c in self.clouds.values()}))
            self.clouds[name] = cloud
        return cloud

    def _judge_clouds(self, now: float) -> None:
        """Up, down or unknown for each cloud, from its IaaS's health and the federation."""
        fresh = now - self.listing_at <= max(3 * self.settings.tick,
                                             self.settings.poll_timeout + 2 * self.settings.tick)
        listing = self.listing if fresh else None
        by_cloud = {e["cloud"]: e for e in self.endpoints if e.get("cloud")}
        for cloud in self.clouds.values():
            endpoint = by_cloud.get(cloud.name)
            status, reason = "up", None
            if endpoint is not None and endpoint.get("ok") is False:
                status = "down"
                reason = f"its IaaS at {endpoint['url']} does not answer"
            elif listing is not None and cloud.name not in listing:
                status, reason = "down", "it left the federation"
            elif listing is None and not (endpoint and endpoint.get("ok")):
                status, reason = "unknown", "no IaaS that answers can see it"
            if listing is not None and cloud.name in listing:
                cloud.counts = listing[cloud.name]
            self._cloud_changed(cloud, status, reason, now)

    def _cloud_changed(self, cloud: Cloud, status: str, reason: str | None, now: float) -> None:
        if status == cloud.status:
            cloud.reason = reason
            return
        was = cloud.status
        cloud.status, cloud.reason, cloud.since = status, reason, now
        if status == "down" and cloud.ever_up:
            robots = sum(1 for r in self.robots.values() if r.row[1] == cloud.name)
            self.alert("danger", "cloud",
                       f"{cloud.name} is down: {reason}. Its {robots} robot"
                       f"{'' if robots == 1 else 's'} are greyed with the time since last heard.",
                       now, cloud=cloud.name)
        elif status == "up" and cloud.ever_up:
            text = "is back: its robots report again" if was == "down" else "is seen again"
            self.alert("ok", "cloud", f"{cloud.name} {text}.", now, cloud=cloud.name)
        elif status == "up" and now - self.started > STARTUP_GRACE:
            self.alert("info", "cloud", f"{cloud.name} joined the federation.", now,
                       cloud=cloud.name)
        if status == "up":
            cloud.ever_up = True

    def _judge_endpoints(self, now: float) -> None:
        """Alerts for what no cloud stands for: an IaaS never heard, or none answering."""
        for endpoint in self.endpoints:
            url = str(endpoint["url"])
            ok = endpoint.get("ok")
            before = self._endpoint_ok.get(url)
            self._endpoint_ok[url] = ok
            if endpoint.get("cloud") or ok is before or ok is None:
                continue
            if ok is False:
                self.alert("warning", "iaas",
                           f"The IaaS at {url} does not answer: {endpoint.get('error')}", now)
            elif before is False:
                self.alert("ok", "iaas", f"The IaaS at {url} answers again.", now)
        answering = any(e.get("ok") for e in self.endpoints)
        checked = all(e.get("ok") is not None for e in self.endpoints)
        if self.endpoints and checked and answering is not self._any_answering:
            if not answering:
                self.alert("danger", "iaas", "No IaaS answers: the page shows the fleet and the "
                                             "requests as last heard.", now)
            elif self._any_answering is False:
                self.alert("ok", "iaas", "An IaaS answers again.", now)
            self._any_answering = answering

    # --- requests ----------------------------------------------------------------
    def _alert_history(self, summary: Mapping[str, Any], entry: Mapping[str, Any]) -> None:
        at = _when(entry.get("at"))
        if at is None or at < self.started:
            return
        name = _request_name(summary)
        detail = str(entry.get("detail") or "").strip()
        if entry.get("kind") == "state" and entry.get("state") in ("failed", "rejected"):
            reason = detail or str(summary.get("reason") or "no reason given")
            level = "danger" if entry.get("state") == "failed" else "warning"
            self.alert(level, "request", f"{name} {entry['state']}: {reason.rstrip('.')}.", at,
                       request=summary["id"])
        elif entry.get("kind") == "event" and ROBOT_EVENT.match(detail):
            text = f"{name}: {detail.rstrip('.')}."
            level = "warning" if " failed" in detail.split(" replaced", 1)[0] else "info"
            if "replaced by" in detail and summary.get("time") is not None:
                text += (f" The coalition's time is now {fmt_duration(summary['time'])} robot "
                         f"time, its cost {summary['cost']:,.2f} {self.settings.currency}.")
            self.alert(level, "robot", text, at, request=summary["id"])

    def _evict_requests(self) -> None:
        if len(self.requests) <= MAX_FOLLOWED:
            return
        finished = sorted((f.summary["created_at"], i) for i, f in self.requests.items()
                          if f.summary["state"] in FINAL_STATES)
        for _, request_id in finished[: len(self.requests) - MAX_FOLLOWED]:
            del self.requests[request_id]

    # --- what goes out --------------------------------------------------------------
    def _robot_rows(self, now: float) -> dict[str, list[Any]]:
        down = {c.name for c in self.clouds.values() if c.status != "up"}
        rows: dict[str, list[Any]] = {}
        for robot_id, robot in list(self.robots.items()):
            age = now - robot.heard
            if age > FORGET_AFTER:
                del self.robots[robot_id]
                continue
            stale = age > self.settings.stale_after or robot.row[1] in down
            rows[robot_id] = [*robot.row, round(robot.heard, 1) if stale else None]
        return rows

    def capability_offers(self, now: float) -> list[dict[str, Any]]:
        """Capabilities the live fleet has, with how many fresh idle robots bring each."""
        counts: dict[tuple[str, str], list[int]] = {}
        down = {c.name for c in self.clouds.values() if c.status != "up"}
        for robot in self.robots.values():
            fresh = now - robot.heard <= self.settings.stale_after and robot.row[1] not in down
            idle = fresh and robot.row[COLUMN["status"]] == "idle"
            for name in robot.row[COLUMN["capabilities"]]:
                kind = robot.kinds.get(name, "sensing")
                count = counts.setdefault((kind, name), [0, 0])
                count[0] += 1
                count[1] += int(idle)
        order = sorted(counts, key=lambda key: (key[0] != "actuating", key[1]))
        return [{"name": n, "kind": k, "robots": counts[k, n][0], "idle": counts[k, n][1]}
                for k, n in order]

    def known_capabilities(self) -> set[str]:
        return {n for r in self.robots.values() for n in r.row[COLUMN["capabilities"]]}

    def clouds_json(self) -> list[dict[str, Any]]:
        out = []
        for cloud in sorted(self.clouds.values(), key=lambda c: c.name):
            robots = [r for r in self.robots.values() if r.row[1] == cloud.name]
            counts = {
                "robots": len(robots),
                "idle": sum(1 for r in robots if r.row[2] == "idle"),
                "offline": sum(1 for r in robots if r.row[2] == "offline"),
            }
            out.append({"name": cloud.name, "colour": cloud.colour, "status": cloud.status,
                        "since": round(cloud.since, 3), "reason": cloud.reason, "iaas": cloud.iaas,
                        **counts})
        return out

    def config_json(self) -> dict[str, Any]:
        s = self.settings
        return {"forest": s.forest.as_json(), "currency": s.currency, "time_scale": self.time_scale,
                "stale_after": s.stale_after, "silent_after": s.silent_after, "tick": s.tick,
                "iaas": list(s.iaas),
                "limits": self.limits,
                "states": {"all": list(REQUEST_STATES),
                           "final": [s for s in REQUEST_STATES if s in FINAL_STATES]}}

    def publish(self, now: float) -> dict[str, Any]:
        """What changed since the last call, as one delta; the published state moves on."""
        self._judge_endpoints(now)
        self._judge_clouds(now)
        delta: dict[str, Any] = {"now": round(now, 3)}
        rows = self._robot_rows(now)
        added, changed = [], []
        for robot_id, row in rows.items():
            before = self._published_robots.get(robot_id)
            if before is None:
                added.append(row)
                continue
            change: list[Any] = [robot_id]
            for i in range(1, len(row)):
                if row[i] != before[i]:
                    change += [i, row[i]]
            if len(change) > 1:
                changed.append(change)
        removed = [i for i in self._published_robots if i not in rows]
        self._published_robots = rows
        robots: dict[str, Any] = {}
        if added:
            robots["add"] = added
        if changed:
            robots["set"] = changed
        if removed:
            robots["del"] = removed
        if robots:
            delta["robots"] = robots
        parts = {
            "config": self.config_json(),
            "clouds": self.clouds_json(),
            "endpoints": self.endpoints,
            "capabilities": self.capability_offers(now),
        }
        for name, value in parts.items():
            if self._published.get(name) != value:
                self._published[name] = value
                delta[name] = value
        if self._new_alerts:
            delta["alerts"] = [a.as_json() for a in self._new_alerts]
            self._new_alerts = []
        if self._changed_requests:
            delta["requests"] = [self.requests[i].summary for i in sorted(self._changed_requests)
                                 if i in self.requests]
            self._changed_requests = set()
        return delta

    def snapshot(self, now: float) -> dict[str, Any]:
        """Everything as last published, for a page that starts (or starts over)."""
        followed = sorted(self.requests.values(), key=lambda f: f.summary["created_at"],
                          reverse=True)[:REQUESTS_IN_SNAPSHOT]
        return {
            "now": round(now, 3),
            "config": self._published.get("config", self.config_json()),
            "clouds": self._published.get("clouds", []),
            "endpoints": self._published.get("endpoints", []),
            "capabilities": self._published.get("capabilities", []),
            "robots": {"columns": list(ROBOT_COLUMNS),
                       "rows": list(self._published_robots.values())},
            "alerts": [a.as_json() for a in list(self.alerts)[-ALERTS_IN_SNAPSHOT:]],
            "requests": [f.summary for f in followed],
        }

    def robots_json(self, now: float) -> list[dict[str, Any]]:
        """The fleet as the page knows it, one object a robot (``GET /api/robots``)."""
        rows = self._robot_rows(now)
        return [dict(zip(ROBOT_COLUMNS, row, strict=True)) for row in rows.values()]


def _robot_row(data: Any) -> tuple[list[Any], dict[str, str]] | None:
    if not isinstance(data, Mapping):
        return None
    robot_id, cloud = data.get("id"), data.get("cloud")
    position = data.get("position")
    if not (_name(robot_id) and _name(cloud) and isinstance(position, list)
            and len(position) == 2):
        return None
    x, y = _number(position[0]), _number(position[1])
    if x is None or y is None:
        return None
    status = data.get("status") if data.get("status") in STATUSES else "offline"
    battery = _number(data.get("battery"), 0.0) or 0.0
    kinds = capability_kinds(data)
    progress: Mapping[str, Any] = (
        data["progress"] if isinstance(data.get("progress"), Mapping) else {}
    )
    phase = progress.get("phase") if isinstance(progress.get("phase"), str) else None
    value = _number(progress.get("progress"))
    request = data.get("request") if _name(data.get("request"), 200) else None
    # Rounded to what the map and the tables can show: finer changes are not news.
    row = [robot_id, cloud, status, round(x), round(y), round(battery), sorted(kinds),
           request, phase, None if value is None else round(value, 2)]
    return row, kinds


def request_summary(record: Mapping[str, Any], cloud: str | None) -> dict[str, Any] | None:
    """The part of a request the tables, the ETAs and the alerts need."""
    request_id, state = record.get("id"), record.get("state")
    if not (_name(request_id, 128) and _name(state)):
        return None
    task: Mapping[str, Any] = record["task"] if isinstance(record.get("task"), Mapping) else {}
    needs: dict[str, Any] = {}
    for kind in ("actuating", "sensing"):
        if isinstance(task.get(kind), Mapping):
            needs.update(task[kind])
    coalition: list[Any] = record["coalition"] if isinstance(record.get("coalition"), list) else []
    history: list[Any] = record["history"] if isinstance(record.get("history"), list) else []
    return {
        "id": request_id,
        "label": _text(record.get("label")),
        "state": state,
        "reason": _text(record.get("reason")),
        "created_at": record.get("created_at"),
        "updated_at": record.get("updated_at"),
        "cloud": cloud,
        "location": task.get("location"),
        "needs": needs,
        "max_robots": task.get("max_robots"),
        "max_cost": task.get("max_cost"),
        "max_time": task.get("max_time"),
        "priority": task.get("priority"),
        "time": _number(record.get("time")),
        "cost": _number(record.get("cost")),
        "robots": [[a.get("robot"), a.get("cloud"), _number(a.get("time")),
                    _number(a.get("cost"))]
                   for a in coalition if isinstance(a, Mapping)],
        "rev": f"{record.get('updated_at')}/{len(history)}",
    }


# The task's field names as the page's form shows them (js/util.js ``humanize``).
FIELD_WORDS = re.compile(r"\b(max_time|max_cost|max_robots|min_battery)\b")
MAX_ALERT_CHARS = 400


def humanize(text: str) -> str:
    words = FIELD_WORDS.sub(lambda m: m.group(1).replace("_", " "), text)
    return words if len(words) <= MAX_ALERT_CHARS else words[: MAX_ALERT_CHARS - 1] + "…"


def one_line(text: str) -> str:
    """Text from elsewhere (an IaaS's sentence, a label) as one log line no one can forge."""
    return CONTROL.sub(lambda m: f"\\x{ord(m.group()):02x}", text)


def _request_name(summary: Mapping[str, Any]) -> str:
    label = summary.get("label")
    return f"Request “{label}” ({summary['id']})" if label else f"Request {summary['id']}"


def dumps(value: Any) -> bytes:
    """Compact JSON for the wire."""
    return json.dumps(value, separators=(",", ":"), ensure_ascii=False).encode()
