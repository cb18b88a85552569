"""The overlay in memory: several clouds in one process, for fast tests of Home and the view.

``MemoryNetwork`` joins clouds; each gets a ``MemoryOverlay`` that calls the
other clouds' desks directly, through the same JSON and the same handlers as
``ZenohOverlay`` (``desk_handlers``, ``answer``), so a desk sees what it would
see over Zenoh. A command's origin is the calling overlay's cloud: as a
router with mutual TLS guarantees, a cloud here cannot send as another.

Faults: ``cut(cloud)`` makes a cloud unreachable both ways (as a cloud killed
or cut off: gone from the live clouds too), ``mute(cloud)`` leaves it live but
answering nobody (as a cloud too slow for the timeout), ``mend(cloud)`` undoes
either. Every call is recorded in
``calls`` as ``(sender, receiver, key name)``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import TypeVar

import pydantic

from robocloud.errors import RoboCloudError
from robocloud.federation.messages import (
    CloudInfo,
    FleetReply,
    IdleQuery,
    StatusQuery,
    StatusReply,
    decode_idle_reply,
)
from robocloud.federation.overlay import (
    Gathered,
    HomeCommands,
    HomeDesk,
    Unreachable,
    answer,
    desk_handlers,
)
from robocloud.fleet.link import LatestStates, RobotLink, StateListener
from robocloud.fleet.messages import State

M = TypeVar("M", bound=pydantic.BaseModel)


class MemoryNetwork:
    def __init__(self) -> None:
        self._desks: dict[str, HomeDesk] = {}
        self._overlays: dict[str, MemoryOverlay] = {}
        self._cut: set[str] = set()
        self._muted: set[str] = set()
        self._lock = threading.Lock()
        self.calls: list[tuple[str, str, str]] = []

    def join(
        self,
        cloud: str,
        desk: HomeDesk,
        link: RobotLink | None = None,
        offline_after: float = 5.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> MemoryOverlay:
        """Add a cloud: its desk answers the others; its link's states reach their watchers."""
        overlay = MemoryOverlay(self, cloud, offline_after, clock)
        with self._lock:
            self._desks[cloud] = desk
            self._overlays[cloud] = overlay
        if link is not None:
            link.on_state(lambda state: self._publish(cloud, state))
        return overlay

    def cut(self, cloud: str) -> None:
        with self._lock:
            self._cut.add(cloud)

    def mute(self, cloud: str) -> None:
        with self._lock:
            self._muted.add(cloud)

    def mend(self, cloud: str) -> None:
        with self._lock:
            self._cut.discard(cloud)
            self._muted.discard(cloud)

    def trusts(self, cloud: str) -> Callable[[str], bool]:
        """Whom ``cloud`` trusts: its desk says."""
        with self._lock:
            desk = self._desks.get(cloud)
        return desk.trusts if desk is not None else (lambda _: False)

    def live(self) -> list[str]:
        with self._lock:
            return sorted(set(self._desks) - self._cut)

    def call(
        self, sender: str, receiver: str, name: str, message: pydantic.BaseModel | None
    ) -> bytes:
        """The reply's JSON, or ``Unreachable`` as ``ZenohOverlay`` raises it."""
        with self._lock:
            self.calls.append((sender, receiver, name))
            away = {sender, receiver} & self._cut or receiver in self._muted
            desk = None if away else self._desks.get(receiver)
        if desk is None:
            raise Unreachable(f"{receiver} is not reachable on the overlay.")
        payload = message.model_dump_json().encode() if message is not None else b""
        try:
            return answer(desk_handlers(desk)[name], sender, payload)
        except RoboCloudError as error:
            raise Unreachable(f"{receiver} did not answer the {name}: {error.message}.") from error

    def _publish(self, cloud: str, state: State) -> None:
        with self._lock:
            if cloud in self._cut:
                return
            watchers = [o for name, o in self._overlays.items() if name not in self._cut]
        for overlay in watchers:
            overlay.heard(cloud, state)


class MemoryOverlay(HomeCommands):
    """One cloud's overlay on a ``MemoryNetwork`` (an ``Overlay``)."""

    def __init__(
        self,
        network: MemoryNetwork,
        cloud: str,
        offline_after: float = 5.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._network = network
        self._cloud = cloud
        self._watched = LatestStates("*", offline_after, clock)
        self._watching: set[tuple[str, str]] = set()
        self._lock = threading.Lock()

    @property
    def cloud(self) -> str:
        return self._cloud

    def clouds(self) -> list[str]:
        """The live clouds this one trusts (as ``ZenohOverlay``'s presence keeps them)."""
        if not self._reachable():
            return [self.cloud]
        trusts = self._network.trusts(self.cloud)
        return [c for c in self._network.live() if trusts(c)]

    def infos(self) -> list[CloudInfo]:
        return sorted(
            (self._ask(c, "info", None, CloudInfo) for c in self._everyone(with_self=True)),
            key=lambda info: info.cloud,
        )

    def gather_idle(self, query: IdleQuery, timeout: float | None = None) -> Gathered:
        started = time.perf_counter()
        gathered = Gathered()
        for cloud in self._everyone():
            try:
                reply = self._network.call(self.cloud, cloud, "idle", query)
            except Unreachable:
                gathered.missing.append(cloud)
                continue
            gathered.replies[cloud] = decode_idle_reply(reply)
        gathered.elapsed_ms = (time.perf_counter() - started) * 1000
        return gathered

    def fleets(self) -> list[FleetReply]:
        return [self._ask(cloud, "fleet", None, FleetReply) for cloud in self._everyone()]

    def _command(self, home: str, name: str, message: pydantic.BaseModel, model: type[M]) -> M:
        return self._ask(home, name, message, model)

    def status(self, origin: str, query: StatusQuery) -> StatusReply:
        return self._ask(origin, "status", query, StatusReply)

    def watch(self, cloud: str, robot_id: str) -> None:
        with self._lock:
            self._watching.add((cloud, robot_id))

    def unwatch(self, cloud: str, robot_id: str) -> None:
        with self._lock:
            self._watching.discard((cloud, robot_id))

    def watched(self) -> set[tuple[str, str]]:
        with self._lock:
            return set(self._watching)

    def ages(self) -> dict[str, float]:
        return self._watched.ages()

    def states(self) -> dict[str, State]:
        return self._watched.states()

    def on_state(self, listener: StateListener) -> Callable[[], None]:
        return self._watched.add_listener(listener)

    def close(self) -> None:
        self._network.cut(self.cloud)

    def heard(self, cloud: str, state: State) -> None:
        """A state published by a robot of ``cloud`` (the network calls this)."""
        with self._lock:
            wanted = (cloud, state.id) in self._watching
        if wanted:
            self._watched.accept(state)

    def _reachable(self) -> bool:
        return self.cloud in self._network.live()

    def _everyone(self, with_self: bool = False) -> list[str]:
        return [c for c in self.clouds() if with_self or c != self.cloud]

    def _ask(self, cloud: str, name: str, message: pydantic.BaseModel | None, model: type[M]) -> M:
        return model.model_validate_json(self._network.call(self.cloud, cloud, name, message))
