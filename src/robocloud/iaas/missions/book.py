"""The book of missions (``MissionBook``): the missions this IaaS runs, live, in memory.

Every mission is also in the request store (``RequestStore.save_mission``:
its latest JSON, written at each change of its state or history), which is
what is read for a mission this process does not run (finished, or from
before a restart). A restarted IaaS does not resume a mission: it ends the
unfinished ones as failed, and their robots, still at a task, are stopped
as strays (robots working for a request the IaaS does not run).
At most ``MAX_MISSIONS`` are kept live; past it the oldest finished ones go.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

from robocloud.domain import is_final
from robocloud.domain.mission_ids import MISSION_ID, new_mission_id
from robocloud.iaas.missions.plans import RobotRun, TaskRun
from robocloud.planning.mission import Mission
from robocloud.storage import RequestStore

MAX_MISSIONS = 10_000
MISSION_STATES = ("planning", "underway", "completed", "rejected", "failed", "canceled")


@dataclass
class MissionRecord:
    """A mission and how it goes; changed only by its runner, on the event loop."""

    id: str
    application: str
    label: str | None
    body: dict[str, Any]  # what was posted, as validated (an Idempotency-Key's retry compares it)
    idempotency_key: str | None
    mission: Mission
    time_limit: float
    created_at: float
    updated_at: float
    state: str = "planning"
    reason: str | None = None
    started_at: float | None = None
    plan: dict[str, Any] | None = None  # the plan's summary (version, makespan, ...)
    tasks: dict[int, TaskRun] = field(default_factory=dict)  # by number, from 1
    robots: dict[str, RobotRun] = field(default_factory=dict)
    history: list[dict[str, Any]] = field(default_factory=list)

    def note(self, at: float, note: str, state: str | None = None) -> None:
        if state is not None:
            self.state = state
        self.updated_at = at
        self.history.append({"at": at, "state": self.state, "note": note})


class MissionBook:
    def __init__(self, store: RequestStore) -> None:
        self.store = store
        self._lock = threading.Lock()  # Home asks from the overlay's threads
        self._missions: OrderedDict[str, MissionRecord] = OrderedDict()  # oldest first
        self._keys: dict[tuple[str, str], str] = {}

    def create(
        self,
        application: str,
        mission: Mission,
        body: dict[str, Any],
        label: str | None,
        time_limit: float,
        idempotency_key: str | None,
        now: float,
    ) -> tuple[MissionRecord, bool]:
        """A new mission (True), or the one the Idempotency-Key was used for (False)."""
        with self._lock:
            if idempotency_key is not None:
                known = self._keys.get((application, idempotency_key))
                if known is not None and known in self._missions:
                    return self._missions[known], False
            record = MissionRecord(
                id=new_mission_id(),
                application=application,
                label=label,
                body=body,
                idempotency_key=idempotency_key,
                mission=mission,
                time_limit=time_limit,
                created_at=now,
                updated_at=now,
            )
            record.note(now, "received")
            self._missions[record.id] = record
            if idempotency_key is not None:
                self._keys[(application, idempotency_key)] = record.id
            self._prune()
            return record, True

    def get(self, mission_id: str, application: str | None = None) -> MissionRecord | None:
        record = self._missions.get(mission_id)
        if record is None or (application is not None and record.application != application):
            return None
        return record

    def status(self, mission_id: str) -> tuple[bool, bool] | None:
        """For a mission id: (known, final), what another cloud that lent robots asks;
        None for any other id (a request's)."""
        if not MISSION_ID.fullmatch(mission_id):
            return None
        record = self._missions.get(mission_id)
        if record is not None:
            return True, is_final(record.state)
        stored = self.store.mission(mission_id)
        return (False, False) if stored is None else (True, is_final(stored.state))

    def _prune(self) -> None:
        """Past ``MAX_MISSIONS``, forget the oldest finished missions (the lock held)."""
        if len(self._missions) <= MAX_MISSIONS:
            return
        for mission_id in [m for m, r in self._missions.items() if is_final(r.state)]:
            record = self._missions.pop(mission_id)
            if record.idempotency_key is not None:
                self._keys.pop((record.application, record.idempotency_key), None)
            if len(self._missions) <= MAX_MISSIONS:
                return
