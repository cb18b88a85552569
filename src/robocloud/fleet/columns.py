"""The robots' latest states as rows of arrays, kept as the states arrive.

``LatestStates`` (``robocloud.fleet.link``) writes a robot's row when a state
says something new about it (a new robot, a new status, battery, position,
...), and only its receive time otherwise; a selection takes a snapshot
(``robocloud.selection.columns.FleetColumns``) and filters it with one
vectorised mask instead of visiting every robot.

Not thread-safe: its owner holds a lock around every call.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from robocloud.fleet.messages import State
from robocloud.selection.columns import OFFLINE, STATUS_CODES, CapabilitySets, FleetColumns

_FIRST_CAPACITY = 1024


class StateColumns:
    """One row per robot (its slot, in order of arrival) and the robots' ids in order."""

    def __init__(self, capacity: int = _FIRST_CAPACITY) -> None:
        self.sets = CapabilitySets()
        self._slot: dict[str, int] = {}
        self._ids: list[str] = []
        self._alloc(max(capacity, 1))
        # The slots in id order, the sorted ids (a list, an array) and each id's
        # row; None when a robot joined.
        self._order: tuple[np.ndarray, list[str], np.ndarray, dict[str, int]] | None = None

    @classmethod
    def of(cls, states: Mapping[str, State], received: Mapping[str, float]) -> StateColumns:
        """Columns of ``states``, received at ``received`` (after robots were forgotten, say)."""
        columns = cls(len(states) + _FIRST_CAPACITY)
        for rid, state in states.items():
            columns.put(state, received[rid], changed=True)
        return columns

    def _alloc(self, capacity: int) -> None:
        self._cloud = np.empty(capacity, dtype=object)
        self._status = np.zeros(capacity, dtype=np.int8)
        self._battery = np.zeros(capacity)
        self._x = np.zeros(capacity)
        self._y = np.zeros(capacity)
        self._speed = np.ones(capacity)
        self._travel = np.zeros(capacity)
        self._set = np.zeros(capacity, dtype=np.int64)
        self._at = np.zeros(capacity)

    def _arrays(self) -> list[np.ndarray[Any, Any]]:
        return [self._cloud, self._status, self._battery, self._x, self._y, self._speed,
                self._travel, self._set, self._at]  # fmt: skip

    def _grow(self) -> None:
        old = self._arrays()
        n = len(self._ids)
        self._alloc(2 * old[0].shape[0])
        for before, after in zip(old, self._arrays(), strict=True):
            after[:n] = before[:n]

    def __len__(self) -> int:
        return len(self._ids)

    def put(self, state: State, now: float, changed: bool) -> None:
        """``state`` was received at ``now``; ``changed``: it may say something new."""
        slot = self._slot.get(state.id)
        if slot is None:
            slot = len(self._ids)
            if slot == self._at.shape[0]:
                self._grow()
            self._slot[state.id] = slot
            self._ids.append(state.id)
            self._order = None
            changed = True
        if changed:
            self._cloud[slot] = state.cloud
            self._status[slot] = STATUS_CODES[state.status]
            self._battery[slot] = state.battery
            self._x[slot], self._y[slot] = state.position
            self._speed[slot] = state.speed
            self._travel[slot] = state.travel_cost_per_m
            self._set[slot] = self.sets.index(state.capabilities)
        self._at[slot] = now

    def snapshot(self, stale_before: float) -> FleetColumns:
        """The robots in id order; offline those received before ``stale_before``."""
        if self._order is None:
            ids = self._ids
            slots = np.array(sorted(range(len(ids)), key=ids.__getitem__), dtype=np.int64)
            in_order = [ids[i] for i in slots.tolist()]
            rows = {rid: row for row, rid in enumerate(in_order)}
            self._order = (slots, in_order, np.array(in_order, dtype=object), rows)
        slots, in_order, id_array, rows = self._order
        status = self._status[slots]
        status[self._at[slots] < stale_before] = OFFLINE
        return FleetColumns(
            ids=in_order,
            id_array=id_array,
            row_of=rows,
            cloud=self._cloud[slots],
            status=status,
            battery=self._battery[slots],
            x=self._x[slots],
            y=self._y[slots],
            speed=self._speed[slots],
            travel=self._travel[slots],
            capability_set=self._set[slots],
            sets=self.sets,
            set_count=len(self.sets),
        )
