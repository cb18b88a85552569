"""``MemoryRequestStore``: the request store in a dict, for fast tests.

It answers exactly as ``SqlRequestStore`` does (the same checks, sentences
and JSON round trip), behind one lock; nothing survives the process.
"""

from __future__ import annotations

import builtins
import threading
from collections.abc import Sequence
from dataclasses import dataclass, replace
from datetime import datetime
from typing import Any

from robocloud.domain import ACTIVE_STATES, FINAL_STATES
from robocloud.storage import rules
from robocloud.storage.records import RequestRecord, StateChange, new_request_id


@dataclass(frozen=True)
class _Hold:
    request_id: str
    expires_at: datetime | None


class MemoryRequestStore:
    """A ``RequestStore`` in memory. ``clock`` (UTC-aware datetimes) is for tests."""

    def __init__(self, clock: rules.Clock | None = None) -> None:
        self._clock = rules.StoreClock(clock)
        self._lock = threading.RLock()
        self.local_reads = True
        # Stored as JSON text, like the SQL store, so callers never share a dict
        # with the store and both stores refuse the same values.
        self._requests: dict[str, tuple[RequestRecord, str, str | None]] = {}
        self._keys: dict[tuple[str, str], str] = {}
        self._holds: dict[str, _Hold] = {}

    # requests

    def create_request(
        self,
        application: str,
        task: dict[str, Any],
        label: str | None = None,
        idempotency_key: str | None = None,
    ) -> tuple[RequestRecord, bool]:
        rules.check_name(application, "application", "application")
        rules.check_optional_name(idempotency_key, "idempotency_key", "idempotency_key")
        rules.check_text(label, "label")
        task_text = rules.dump_json(task, "task")
        with self._lock:
            if idempotency_key is not None:
                existing = self._keys.get((application, idempotency_key))
                if existing is not None:
                    return self._record(existing), False
            request_id = new_request_id()
            while request_id in self._requests:
                request_id = new_request_id()
            now = self._clock()
            record = RequestRecord(
                id=request_id,
                application=application,
                label=label,
                task={},
                state="received",
                reason=None,
                created_at=now,
                updated_at=now,
                selection=None,
                idempotency_key=idempotency_key,
                history=(StateChange("received", now),),
            )
            self._requests[request_id] = (record, task_text, None)
            if idempotency_key is not None:
                self._keys[(application, idempotency_key)] = request_id
            return self._record(request_id), True

    def get(self, request_id: str, application: str | None = None) -> RequestRecord | None:
        with self._lock:
            if request_id not in self._requests:
                return None
            record = self._record(request_id)
        if application is not None and record.application != application:
            return None
        return record

    def list(
        self,
        application: str,
        state: str | None = None,
        limit: int = 50,
        before: str | None = None,
    ) -> tuple[builtins.list[RequestRecord], str | None]:
        if state is not None:
            rules.check_state(state)
        rules.check_limit(limit)
        with self._lock:
            mine = [r for r, _, _ in self._requests.values() if r.application == application]
            if before is not None:
                cursor = self._requests.get(before)
                if cursor is None or cursor[0].application != application:
                    raise rules.bad_cursor(before)
                edge = (cursor[0].created_at, cursor[0].id)
                mine = [r for r in mine if (r.created_at, r.id) < edge]
            if state is not None:
                mine = [r for r in mine if r.state == state]
            mine.sort(key=lambda r: (r.created_at, r.id), reverse=True)
            page = [self._record(r.id) for r in mine[:limit]]
        return page, (page[-1].id if len(mine) > limit else None)

    def transition(
        self,
        request_id: str,
        new_state: str,
        reason: str | None = None,
        detail: str | None = None,
        selection: dict[str, Any] | None = None,
    ) -> RequestRecord:
        selection_text = rules.check_transition(new_state, reason, detail, selection)
        with self._lock:
            record, task_text, old_selection = self._stored(request_id)
            rules.check_move(request_id, record.state, new_state)
            now = self._clock()
            record = replace(
                record,
                state=new_state,
                reason=record.reason if reason is None else reason,
                updated_at=now,
                history=(*record.history, StateChange(new_state, now, detail)),
            )
            self._requests[request_id] = (
                record,
                task_text,
                old_selection if selection_text is None else selection_text,
            )
            if new_state in FINAL_STATES:
                self._release(request_id, None)
            return self._record(request_id)

    def add_event(self, request_id: str, detail: str) -> RequestRecord:
        rules.check_text(detail, "detail")
        with self._lock:
            record, task_text, selection_text = self._stored(request_id)
            now = self._clock()
            record = replace(
                record,
                updated_at=now,
                history=(*record.history, StateChange(record.state, now, detail, "event")),
            )
            self._requests[request_id] = (record, task_text, selection_text)
            return self._record(request_id)

    def set_selection(self, request_id: str, selection: dict[str, Any]) -> RequestRecord:
        selection_text = rules.dump_json(selection, "selection")
        with self._lock:
            record, task_text, _ = self._stored(request_id)
            record = replace(record, updated_at=self._clock())
            self._requests[request_id] = (record, task_text, selection_text)
            return self._record(request_id)

    def active(self) -> builtins.list[RequestRecord]:
        with self._lock:
            found = [r for r, _, _ in self._requests.values() if r.state in ACTIVE_STATES]
            found.sort(key=lambda r: (r.created_at, r.id))
            return [self._record(r.id) for r in found]

    # reservations

    def reserve(
        self,
        request_id: str,
        robot_ids: Sequence[str],
        lease_seconds: float | None = None,
    ) -> builtins.list[str]:
        robots = rules.check_robots(robot_ids)
        with self._lock:
            now = self._clock()
            expires_at = rules.lease_end(now, lease_seconds)
            record, _, _ = self._stored(request_id)
            rules.check_can_hold_robots(request_id, record.state)
            self._drop_expired(robots, now)
            taken = [
                robot
                for robot in robots
                if robot in self._holds and self._holds[robot].request_id != request_id
            ]
            if taken:
                return taken
            for robot in robots:
                held = self._holds.get(robot)
                if held is None:
                    self._holds[robot] = _Hold(request_id, expires_at)
                elif held.expires_at is not None:
                    self._holds[robot] = _Hold(
                        request_id,
                        None if expires_at is None else max(expires_at, held.expires_at),
                    )
            return []

    def confirm(self, request_id: str, robot_ids: Sequence[str]) -> builtins.list[str]:
        return self.reserve(request_id, robot_ids)

    def release(self, request_id: str, robot_ids: Sequence[str] | None = None) -> None:
        robots = None if robot_ids is None else rules.check_robots(robot_ids)
        with self._lock:
            self._release(request_id, robots)

    def replace(
        self,
        request_id: str,
        old_robot: str,
        new_robot: str,
        lease_seconds: float | None = None,
    ) -> builtins.list[str]:
        rules.check_name(old_robot, "a robot id", "old_robot")
        with self._lock:
            taken = self.reserve(request_id, [new_robot], lease_seconds)
            if not taken and old_robot != new_robot:
                self._release(request_id, [old_robot])
            return taken

    def reservations(self, request_id: str | None = None) -> dict[str, str]:
        with self._lock:
            now = self._clock()
            return {
                robot: held.request_id
                for robot, held in sorted(self._holds.items())
                if not rules.is_expired(held.expires_at, now)
                and (request_id is None or held.request_id == request_id)
            }

    def close(self) -> None:
        pass

    # helpers; the caller holds the lock

    def _stored(self, request_id: str) -> tuple[RequestRecord, str, str | None]:
        stored = self._requests.get(request_id)
        if stored is None:
            raise rules.no_such_request(request_id)
        return stored

    def _record(self, request_id: str) -> RequestRecord:
        record, task_text, selection_text = self._requests[request_id]
        return replace(
            record,
            task=rules.load_json(task_text),
            selection=None if selection_text is None else rules.load_json(selection_text),
        )

    def _drop_expired(self, robots: builtins.list[str], now: datetime) -> None:
        for robot in robots:
            held = self._holds.get(robot)
            if held is not None and rules.is_expired(held.expires_at, now):
                del self._holds[robot]

    def _release(self, request_id: str, robots: builtins.list[str] | None) -> None:
        for robot in list(self._holds) if robots is None else robots:
            held = self._holds.get(robot)
            if held is not None and held.request_id == request_id:
                del self._holds[robot]
