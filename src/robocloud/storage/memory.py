"""``MemoryRequestStore``: the request store in a dict, for fast tests.

It answers exactly as ``SqlRequestStore`` does (the same checks, sentences
and JSON round trip), behind one lock; nothing survives the process.

Why one long file: it is the in-memory twin of the four SQL stores
(requests, loans, holds, missions) behind one lock; cut by concern, each part
would need the lock and the shared tables of the others.
"""

from __future__ import annotations

import builtins
import json
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from datetime import datetime
from typing import Any

from robocloud.domain import ACTIVE_STATES, FINAL_STATES
from robocloud.storage import rules
from robocloud.storage.records import (
    Loan,
    MissionRow,
    RequestRecord,
    StateChange,
    new_loan_id,
    new_request_id,
)
from robocloud.storage.store import Outcome, outcome_of


@dataclass(frozen=True)
class _Hold:
    """A robot's one holder: a request of this cloud, or a loan (``loan_id``)."""

    request_id: str | None
    expires_at: datetime | None
    loan_id: str | None = None

    @property
    def holder(self) -> str:
        holder = self.request_id or self.loan_id
        assert holder is not None
        return holder


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
        self._loans: dict[str, Loan] = {}
        # Indexes, as the SQL store's: the live loans of an origin request, by
        # robot; the ended loans an origin is still to be told about.
        self._lent: dict[tuple[str, str], dict[str, str]] = {}
        self._untold: dict[str, set[str]] = {}
        self._missions: dict[str, tuple[MissionRow, str]] = {}  # id -> (row, its JSON)
        self._mission_keys: dict[tuple[str, str], str] = {}

    def together(self, calls: Sequence[Callable[[], Any]]) -> builtins.list[Outcome]:
        """Run ``calls`` in turn, no other thread's call in between."""
        with self._lock:
            return [outcome_of(call) for call in calls]

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

    def by_idempotency_key(self, application: str, idempotency_key: str) -> RequestRecord | None:
        with self._lock:
            request_id = self._keys.get((application, idempotency_key))
            return None if request_id is None else self._record(request_id)

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
                robot: held.holder
                for robot, held in sorted(self._holds.items())
                if not rules.is_expired(held.expires_at, now)
                and (request_id is None or held.request_id == request_id)
            }

    # loans

    def lend(
        self,
        origin: str,
        request_id: str,
        robot_ids: Sequence[str],
        lease_seconds: float,
    ) -> builtins.list[str]:
        rules.check_name(origin, "origin", "origin")
        rules.check_name(request_id, "request_id", "request_id")
        robots = rules.check_robots(robot_ids)
        with self._lock:
            now = self._clock()
            expires_at = rules.check_lease(lease_seconds, now)
            self._drop_expired(robots, now)
            mine = self._lent.get((origin, request_id), {})
            taken = [
                robot
                for robot in robots
                if robot in self._holds
                and (
                    self._holds[robot].loan_id is None
                    or self._holds[robot].loan_id != mine.get(robot)
                )
            ]
            if taken:
                return taken
            for robot in sorted(robots):
                loan_id = mine.get(robot)
                if loan_id is None:
                    loan_id = new_loan_id()
                    self._loans[loan_id] = Loan(
                        id=loan_id,
                        robot=robot,
                        origin=origin,
                        request_id=request_id,
                        state="leased",
                        expires_at=expires_at,
                        created_at=now,
                        updated_at=now,
                        reason=None,
                        tell_origin=False,
                        history=(StateChange("leased", now, f"lent to {origin}"),),
                    )
                    self._holds[robot] = _Hold(None, expires_at, loan_id)
                    self._lent.setdefault((origin, request_id), {})[robot] = loan_id
                    continue
                loan = self._loans[loan_id]
                if loan.expires_at is not None and loan.expires_at < expires_at:
                    self._loans[loan_id] = replace(loan, expires_at=expires_at, updated_at=now)
                    self._holds[robot] = _Hold(None, expires_at, loan_id)
            return []

    def confirm_loans(
        self, origin: str, request_id: str, robot_ids: Sequence[str]
    ) -> builtins.list[str]:
        robots = rules.check_robots(robot_ids)
        with self._lock:
            now = self._clock()
            self._drop_expired(robots, now)
            mine = self._lent.get((origin, request_id), {})
            lost = [robot for robot in robots if robot not in mine]
            if lost:
                return lost
            for robot in robots:
                loan = self._loans[mine[robot]]
                if loan.state == "leased":
                    self._change(loan, now, state="firm", expires_at=None, detail="confirmed")
                    self._holds[robot] = _Hold(None, None, loan.id)
            return []

    def end_loans(
        self,
        origin: str,
        request_id: str,
        robot_ids: Sequence[str] | None,
        why: str,
        *,
        tell_origin: bool = False,
    ) -> builtins.list[Loan]:
        robots = None if robot_ids is None else rules.check_robots(robot_ids)
        rules.check_why(why)
        with self._lock:
            now = self._clock()
            mine = self._lent.get((origin, request_id), {})
            chosen = list(mine) if robots is None else [r for r in robots if r in mine]
            return [self._end(self._loans[mine[r]], now, why, tell_origin) for r in chosen]

    def lapse_loans(self) -> builtins.list[Loan]:
        with self._lock:
            now = self._clock()
            lapsed = [
                robot
                for robot, held in self._holds.items()
                if held.loan_id is not None and rules.is_expired(held.expires_at, now)
            ]
            return self._drop_expired(lapsed, now)

    def loan_of(self, robot_id: str) -> Loan | None:
        with self._lock:
            held = self._holds.get(robot_id)
            if held is None or held.loan_id is None:
                return None
            if rules.is_expired(held.expires_at, self._clock()):
                return None
            return self._loans[held.loan_id]

    def loans(
        self, origin: str | None = None, request_id: str | None = None
    ) -> builtins.list[Loan]:
        with self._lock:
            now = self._clock()
            if origin is not None and request_id is not None:
                ids = list(self._lent.get((origin, request_id), {}).values())
            else:
                ids = [
                    loan_id
                    for (o, _), robots in self._lent.items()
                    if origin is None or o == origin
                    for loan_id in robots.values()
                ]
            found = [self._loans[i] for i in ids]
            found = [
                replace(loan, history=())
                for loan in found
                if loan.live(now) and (request_id is None or loan.request_id == request_id)
            ]
        found.sort(key=lambda loan: (loan.created_at, loan.robot, loan.id))
        return found

    def count_loans(self, origin: str) -> int:
        with self._lock:
            now = self._clock()
            return sum(
                self._loans[loan_id].live(now)
                for (o, _), robots in self._lent.items()
                if o == origin
                for loan_id in robots.values()
            )

    def untold_loans(self, origin: str) -> builtins.list[Loan]:
        with self._lock:
            found = [self._loans[i] for i in self._untold.get(origin, ())]
        found.sort(key=lambda loan: (loan.updated_at, loan.id))
        return found

    def told(self, origin: str, loan_ids: Sequence[str]) -> builtins.list[Loan]:
        ids = rules.check_names(loan_ids, "a loan id", "loan_ids")
        with self._lock:
            now = self._clock()
            untold = self._untold.get(origin, set())
            marked = []
            for loan_id in ids:
                if loan_id in untold:
                    untold.discard(loan_id)
                    loan = self._change(
                        self._loans[loan_id],
                        now,
                        tell_origin=False,
                        detail=f"{origin} was told that the loan ended",
                    )
                    marked.append(loan)
            return marked

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

    def _drop_expired(self, robots: builtins.list[str], now: datetime) -> builtins.list[Loan]:
        """Free the robots whose lease lapsed; a lapsed loan ends. Returns those loans."""
        ended = []
        for robot in robots:
            held = self._holds.get(robot)
            if held is not None and rules.is_expired(held.expires_at, now):
                del self._holds[robot]
                if held.loan_id is not None:
                    ended.append(self._end(self._loans[held.loan_id], now, "the lease lapsed"))
        return ended

    def _change(self, loan: Loan, now: datetime, detail: str, **values: Any) -> Loan:
        state = values.get("state", loan.state)
        loan = replace(
            loan,
            **values,
            updated_at=now,
            history=(
                *loan.history,
                StateChange(state, now, detail, "state" if state != loan.state else "event"),
            ),
        )
        self._loans[loan.id] = loan
        return loan

    def _end(self, loan: Loan, now: datetime, why: str, tell_origin: bool = False) -> Loan:
        held = self._holds.get(loan.robot)
        if held is not None and held.loan_id == loan.id:
            del self._holds[loan.robot]
        robots = self._lent.get((loan.origin, loan.request_id), {})
        robots.pop(loan.robot, None)
        if not robots:
            self._lent.pop((loan.origin, loan.request_id), None)
        if tell_origin:
            self._untold.setdefault(loan.origin, set()).add(loan.id)
        return self._change(
            loan,
            now,
            state="released",
            expires_at=None,
            reason=why,
            tell_origin=tell_origin,
            detail=why,
        )

    def _release(self, request_id: str, robots: builtins.list[str] | None) -> None:
        for robot in list(self._holds) if robots is None else robots:
            held = self._holds.get(robot)
            if held is not None and held.request_id == request_id:
                del self._holds[robot]

    # missions

    def save_mission(self, row: MissionRow) -> MissionRow:
        with self._lock:
            if row.id not in self._missions and row.idempotency_key is not None:
                known = self._mission_keys.get((row.application, row.idempotency_key))
                if known is not None:
                    return self._mission(known)
                self._mission_keys[(row.application, row.idempotency_key)] = row.id
            self._missions[row.id] = (row, json.dumps(row.document))
            return row

    def _mission(self, mission_id: str) -> MissionRow:
        row, document = self._missions[mission_id]
        return replace(row, document=json.loads(document))

    def mission(self, mission_id: str, application: str | None = None) -> MissionRow | None:
        with self._lock:
            if mission_id not in self._missions:
                return None
            row = self._mission(mission_id)
        return row if application in (None, row.application) else None

    def mission_by_key(self, application: str, idempotency_key: str) -> MissionRow | None:
        with self._lock:
            known = self._mission_keys.get((application, idempotency_key))
            return None if known is None else self._mission(known)

    def missions(
        self, application: str, state: str | None, limit: int, before: str | None
    ) -> tuple[builtins.list[MissionRow], str | None]:
        with self._lock:
            rows = sorted(
                (r for r, _ in self._missions.values() if r.application == application),
                key=lambda r: (r.created_at, r.id),
                reverse=True,
            )
            if before is not None:
                cursor = self._missions.get(before)
                if cursor is None:
                    return [], None
                mark = (cursor[0].created_at, before)
                rows = [r for r in rows if (r.created_at, r.id) < mark]
            rows = [r for r in rows if state in (None, r.state)]
            page = [self._mission(r.id) for r in rows[:limit]]
        return page, (page[-1].id if len(rows) > limit else None)

    def unfinished_missions(self) -> builtins.list[MissionRow]:
        with self._lock:
            return [
                self._mission(m) for m, (r, _) in self._missions.items()
                if r.state not in FINAL_STATES
            ]
