"""``SqlMissions``: this IaaS's missions, each its latest JSON (the ``missions`` table).

The mission half of ``SqlRequestStore`` (``robocloud.iaas.missions`` writes a
mission at each change of its state or history). A mission holds no robot in
the store: its robots are held by the IaaS that runs it (``RobotRoutes``)
and lent by their homes.
"""

from __future__ import annotations

import builtins
import json

from sqlalchemy import Connection, Row, and_, insert, or_, select, update
from sqlalchemy.exc import IntegrityError

from robocloud.domain import FINAL_STATES
from robocloud.storage.engine import Database
from robocloud.storage.records import MissionRow
from robocloud.storage.schema import missions


class SqlMissions:
    def __init__(self, db: Database) -> None:
        self._db = db

    def save_mission(self, row: MissionRow) -> MissionRow:
        """Store the mission (new, or its latest JSON); the one its Idempotency-Key
        was already used for, if another."""
        document = json.dumps(row.document)

        def work(conn: Connection) -> MissionRow:
            done = conn.execute(
                update(missions)
                .where(missions.c.id == row.id)
                .values(state=row.state, document=document)
            )
            if done.rowcount:
                return row
            if row.idempotency_key is not None:
                known = conn.execute(
                    select(missions).where(
                        missions.c.application == row.application,
                        missions.c.idempotency_key == row.idempotency_key,
                    )
                ).first()
                if known is not None:
                    return _row(known)
            conn.execute(
                insert(missions).values(
                    id=row.id,
                    application=row.application,
                    idempotency_key=row.idempotency_key,
                    state=row.state,
                    created_at=row.created_at,
                    document=document,
                )
            )
            return row

        try:
            return self._db.run(work, write=True, retry_integrity=True)
        except IntegrityError:  # the key's mission was stored meanwhile by another
            found = self.mission_by_key(row.application, row.idempotency_key or "")
            if found is None:
                raise
            return found

    def mission(self, mission_id: str, application: str | None = None) -> MissionRow | None:
        query = select(missions).where(missions.c.id == mission_id)
        if application is not None:
            query = query.where(missions.c.application == application)
        found = self._db.run(lambda conn: conn.execute(query).first(), write=False)
        return None if found is None else _row(found)

    def mission_by_key(self, application: str, idempotency_key: str) -> MissionRow | None:
        query = select(missions).where(
            missions.c.application == application,
            missions.c.idempotency_key == idempotency_key,
        )
        found = self._db.run(lambda conn: conn.execute(query).first(), write=False)
        return None if found is None else _row(found)

    def missions(
        self, application: str, state: str | None, limit: int, before: str | None
    ) -> tuple[builtins.list[MissionRow], str | None]:
        def work(conn: Connection) -> tuple[builtins.list[MissionRow], str | None]:
            query = select(missions).where(missions.c.application == application)
            if state is not None:
                query = query.where(missions.c.state == state)
            if before is not None:
                cursor = conn.execute(
                    select(missions.c.created_at).where(missions.c.id == before)
                ).first()
                if cursor is None:
                    return [], None
                query = query.where(
                    or_(
                        missions.c.created_at < cursor.created_at,
                        and_(missions.c.created_at == cursor.created_at, missions.c.id < before),
                    )
                )
            rows = conn.execute(
                query.order_by(missions.c.created_at.desc(), missions.c.id.desc()).limit(
                    limit + 1
                )
            ).all()
            page = [_row(r) for r in rows[:limit]]
            return page, (page[-1].id if len(rows) > limit else None)

        return self._db.run(work, write=False)

    def unfinished_missions(self) -> builtins.list[MissionRow]:
        query = select(missions).where(missions.c.state.not_in(sorted(FINAL_STATES)))
        rows = self._db.run(lambda conn: conn.execute(query).all(), write=False)
        return [_row(r) for r in rows]


def _row(row: Row[tuple[object, ...]]) -> MissionRow:
    found = row._mapping
    return MissionRow(
        id=str(found["id"]),
        application=str(found["application"]),
        idempotency_key=found["idempotency_key"],
        state=str(found["state"]),
        created_at=float(found["created_at"]),
        document=json.loads(found["document"]),
    )
