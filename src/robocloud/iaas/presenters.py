"""Stored records and live robot states turned into the API's wire models."""

from __future__ import annotations

from collections.abc import Callable
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

from robocloud.domain import Coalition, Robot
from robocloud.fleet.messages import State
from robocloud.iaas.models import (
    Assignment,
    FrontMember,
    HistoryEntry,
    Progress,
    RequestPublic,
)
from robocloud.iaas.routes import SetAside
from robocloud.selection.choice import choices
from robocloud.storage import RequestRecord

if TYPE_CHECKING:
    from robocloud.iaas.service import RequestService

_FINAL_PHASE = {
    "completed": ("done", 1.0),
    "canceled": ("canceled", None),
    "failed": ("failed", None),
}


def request_public(record: RequestRecord, service: RequestService) -> RequestPublic:
    selection = record.selection or {}
    coalition = None
    assignments = selection.get("assignments") or []
    if assignments:
        coalition = []
        for a in assignments:
            live = (
                service.progress_of(a["robot"])
                if record.id == service.request_of(a["robot"])
                else None
            )
            progress = None
            if live is not None:
                progress = Progress(phase=live[0], progress=live[1])
            elif record.state in _FINAL_PHASE:
                phase, value = _FINAL_PHASE[record.state]
                progress = Progress(phase=phase, progress=1.0 if value else 0.0)
            else:
                progress = Progress(phase="pending", progress=0.0)
            coalition.append(Assignment(progress=progress, **a))
    chosen = selection.get("chosen") or None
    front_json = selection.get("pareto") or []
    current = selection.get("current") or chosen or {}
    return RequestPublic(
        id=record.id,
        label=record.label,
        state=record.state,
        reason=record.reason,
        created_at=record.created_at,
        updated_at=record.updated_at,
        task=record.task,
        coalition=coalition,
        time=current.get("time"),
        cost=current.get("cost"),
        chosen=FrontMember(**chosen) if chosen else None,
        pareto=[FrontMember(**m) for m in front_json],
        choices=choices_of(front_json),
        optimizer=selection.get("optimizer"),
        selection_ms=selection.get("elapsed_ms"),
        history=[
            HistoryEntry(kind=h.kind, state=h.state, at=h.at, detail=h.detail)
            for h in record.history
        ],
    )


def choices_of(front: list[dict[str, Any]]) -> dict[str, int] | None:
    """Where each priority would choose on a stored front (``RequestPublic.choices``)."""
    return choices(
        [Coalition(robots=tuple(m["robots"]), time=m["time"], cost=m["cost"]) for m in front]
    )


def robot_json(
    robot: Robot,
    state: State | None,
    age: float | None,
    request: str | None,
    aside: SetAside | None = None,
    owned: bool = False,
    refused: str | None = None,
) -> dict[str, Any]:
    """One robot of this cloud as ``RobotPublic`` puts it on the wire, as plain JSON values.

    ``request`` (what holds the robot) and the progress of its task are shown
    only when the application asking ``owned`` that request; to others the
    robot is ``reserved`` or ``busy``, for whom they are not told. Plain
    values, not models: ``GET /v1/robots`` builds thousands a page.
    """
    progress = None
    if owned and state is not None and state.task is not None:
        progress = {"phase": state.task.phase, "progress": float(state.task.progress)}
    return {
        "id": robot.id,
        "cloud": robot.cloud,
        "kind": state.kind if state else None,
        "position": [float(v) for v in robot.position],
        "speed": float(robot.speed),
        "battery": shown_battery(robot.battery),
        "status": shown_status(robot.status, request),
        "capabilities": sorted(robot.capabilities),
        "capability_kinds": {n: c.kind for n, c in robot.capabilities.items()},
        "request": request if owned else None,
        "progress": progress,
        "set_aside": set_aside_json(aside),
        "refused": refused,
        "seen_ago": round(age, 3) if age is not None else None,
    }


def refused_robot_json(robot_id: str, cloud: str, why: str) -> dict[str, Any]:
    """A robot of this cloud none of whose states was accepted: its id and why, on the wire."""
    return {
        "id": robot_id,
        "cloud": cloud,
        "kind": None,
        "position": [],
        "speed": 0.0,
        "battery": 0.0,
        "status": "offline",
        "capabilities": [],
        "capability_kinds": {},
        "request": None,
        "progress": None,
        "set_aside": None,
        "refused": why,
        "seen_ago": None,
    }


def set_aside_json(aside: SetAside | None) -> dict[str, Any] | None:
    if aside is None:
        return None
    until = datetime.fromtimestamp(aside.until, UTC).isoformat().replace("+00:00", "Z")
    return {"until": until, "why": aside.why}


def shown_battery(battery: float) -> float:
    """Battery in percent, rounded to 0.1 for display (robots report it with 14 decimals)."""
    return round(float(battery), 1)


def shown_status(status: str, request: str | None) -> str:
    """An idle robot that a request (or a loan) holds is shown as ``reserved``."""
    return "reserved" if status == "idle" and request is not None else status


def remote_robot_json(data: dict[str, Any], owns: Callable[[str], bool]) -> dict[str, Any]:
    """A robot of another cloud, as its home described it (``FleetReply``), on the wire.

    Its request and progress are shown as for this cloud's robots: only to the
    application that ``owns`` the request (a request of this cloud).
    """
    request = data.get("request")
    owned = isinstance(request, str) and owns(request)
    task = data.get("progress")
    progress = None
    if owned and task:
        progress = {"phase": task["phase"], "progress": float(task["progress"])}
    capabilities = data.get("capabilities", {})
    return {
        "id": data["id"],
        "cloud": data["cloud"],
        "kind": data.get("kind"),
        "position": [float(v) for v in data["position"]],
        "speed": float(data["speed"]),
        "battery": shown_battery(data["battery"]),
        "status": data["status"],
        "capabilities": sorted(capabilities),
        "capability_kinds": {n: c["kind"] for n, c in capabilities.items()},
        "request": request if owned else None,
        "progress": progress,
        "set_aside": None,
        "refused": None,
        "seen_ago": None,
    }
