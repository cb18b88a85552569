"""Stored records and live robot states turned into the API's wire models."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from robocloud.iaas.models import (
    Assignment,
    FrontMember,
    HistoryEntry,
    Progress,
    RequestPublic,
    RobotPublic,
)
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
        pareto=[FrontMember(**m) for m in selection.get("pareto", [])],
        optimizer=selection.get("optimizer"),
        selection_ms=selection.get("elapsed_ms"),
        history=[
            HistoryEntry(kind=h.kind, state=h.state, at=h.at, detail=h.detail)
            for h in record.history
        ],
    )


def robot_public(service: RequestService) -> list[RobotPublic]:
    states = service.link.states()
    ages = service.link.ages()
    held = service.store.reservations()
    robots = []
    for robot in service.link.robots():
        state = states.get(robot.id)
        request = held.get(robot.id)
        progress = None
        if state is not None and state.task is not None:
            progress = Progress(phase=state.task.phase, progress=state.task.progress)
        status = robot.status
        if status == "idle" and request is not None:
            status = "reserved"
        robots.append(
            RobotPublic(
                id=robot.id,
                cloud=robot.cloud,
                kind=state.kind if state else None,
                position=list(robot.position),
                speed=robot.speed,
                battery=robot.battery,
                status=status,
                capabilities=sorted(robot.capabilities),
                capability_kinds={n: c.kind for n, c in robot.capabilities.items()},
                request=request,
                progress=progress,
                seen_ago=round(ages[robot.id], 3) if robot.id in ages else None,
            )
        )
    return robots


def remote_robot_public(data: dict[str, Any]) -> RobotPublic:
    """A robot of another cloud, as its home described it (``FleetReply``)."""
    task = data.get("progress")
    progress = None
    if task:
        progress = Progress(phase=task["phase"], progress=task["progress"])
    return RobotPublic(
        id=data["id"],
        cloud=data["cloud"],
        kind=data.get("kind"),
        position=data["position"],
        speed=data["speed"],
        battery=data["battery"],
        status=data["status"],
        capabilities=sorted(data.get("capabilities", {})),
        capability_kinds={n: c["kind"] for n, c in data.get("capabilities", {}).items()},
        request=data.get("request"),
        progress=progress,
    )
