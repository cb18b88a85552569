"""Clouds in one process for fast tests: memory stores and robots, Homes on a MemoryNetwork."""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
from collections.abc import Awaitable, Callable, Iterable, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from typing import Any

from loopback_ports import free_endpoint
from robocloud.domain import Robot, Task
from robocloud.federation.home import Home
from robocloud.federation.lending import Aside, never_aside
from robocloud.federation.memory import MemoryNetwork, MemoryOverlay
from robocloud.federation.messages import LoanQuery
from robocloud.federation.overlay import Overlay, Unreachable, ZenohOverlay
from robocloud.federation.reconcile import LoanReconciler
from robocloud.federation.view import FederationView
from robocloud.fleet import MemoryRobotLink
from robocloud.iaas import lifecycle as lc
from robocloud.iaas.actor import RequestActor, Shell
from robocloud.iaas.routes import RobotRoutes
from robocloud.iaas.selector import SelectorSettings, failed
from robocloud.storage import MemoryRequestStore, RequestStore


def wait_for_commands(overlay: Overlay, home: str, timeout: float = 5.0) -> None:
    """Until ``home`` answers ``overlay``'s commands: a cloud's liveliness token can
    reach another router before the declarations of its command keys do."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            overlay.loans(home, LoanQuery())
            return
        except Unreachable:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


@contextlib.contextmanager
def zenoh_pair(
    home_a: Home, home_b: Home, timeout: float
) -> Iterator[tuple[ZenohOverlay, ZenohOverlay]]:
    """cloud-a's and cloud-b's overlays on real Zenoh routers, joined and ready for commands.

    ``timeout``: how long cloud-a's calls wait.
    """
    import zenoh

    from robocloud.federation.keys import cloud_token
    from robocloud.fleet import open_router, wait_for_liveliness

    b_endpoint = free_endpoint()
    b_session = open_router([b_endpoint])
    a_session = open_router([free_endpoint()], [b_endpoint])
    sessions: list[zenoh.Session] = [a_session, b_session]
    b = ZenohOverlay(b_session, "cloud-b", home_b)
    a = ZenohOverlay(a_session, "cloud-a", home_a, timeout=timeout)
    try:
        assert wait_for_liveliness(a_session, cloud_token("cloud-b", str(b_session.zid())), 5.0)
        wait_for_commands(a, "cloud-b")
        yield a, b
    finally:
        a.close()
        b.close()
        for session in sessions:
            session.close()  # type: ignore[no-untyped-call]


class FakeTime:
    """One clock for the stores (UTC datetimes) and the Homes (monotonic seconds)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._utc = datetime(2030, 1, 1, 12, 0, tzinfo=UTC)
        self._mono = 1000.0

    def utc(self) -> datetime:
        with self._lock:
            return self._utc

    def mono(self) -> float:
        with self._lock:
            return self._mono

    def advance(self, seconds: float) -> None:
        with self._lock:
            self._utc += timedelta(seconds=seconds)
            self._mono += seconds


@dataclass
class Origin:
    """What a cloud's request service says of its requests (its coalitions, ended loans)."""

    coalitions: dict[str, list[str]] = field(default_factory=dict)
    ended: list[tuple[str, str, str, str]] = field(default_factory=list)

    def coalition_robots(self, request_id: str) -> list[str]:
        return sorted(self.coalitions.get(request_id, []))

    def loan_ended(self, request_id: str, robot: str, home: str, why: str) -> None:
        self.ended.append((request_id, robot, home, why))


@dataclass
class Cloud:
    name: str
    store: RequestStore
    link: MemoryRobotLink
    home: Home
    overlay: MemoryOverlay
    view: FederationView
    origin: Origin
    reconciler: LoanReconciler


def robot(cloud: str, i: int, x: float = 10.0) -> Robot:
    return Robot.model_validate(
        {
            "id": f"{cloud[-1]}-{i}",
            "cloud": cloud,
            "position": [x, 0.0],
            "speed": 1.0,
            "battery": 90.0,
            "status": "idle",
            "travel_cost_per_m": 0.1,
            "capabilities": {"grabber": {"kind": "actuating", "time": 20.0, "cost": 3.0}},
        }
    )


def clouds(
    names: Iterable[str],
    robots: int = 3,
    trust: dict[str, list[str]] | None = None,
    time: FakeTime | None = None,
    stores: dict[str, RequestStore] | None = None,
    lease_max: float = 30.0,
    origin_deadline: float = 60.0,
    lend_share: float = 1.0,
    set_aside: dict[str, Callable[[str], Aside | None]] | None = None,
) -> tuple[MemoryNetwork, dict[str, Cloud]]:
    """One cloud per name, each with ``robots`` robots (``a-0``, ``a-1`` ... for cloud-a).

    ``lend_share``: of a cloud's robots one other may hold (all, unless a test says).
    """
    network = MemoryNetwork()
    time = time or FakeTime()
    out = {}
    for name in names:
        store = (stores or {}).get(name) or MemoryRequestStore(time.utc)
        link = MemoryRobotLink(
            name, [robot(name, i, 10.0 * (i + 1)) for i in range(robots)], clock=time.mono
        )
        origin = Origin()
        home = Home(
            name,
            store,
            link,
            (trust or {}).get(name),
            lease_max=lease_max,
            origin_deadline=origin_deadline,
            lend_share=lend_share,
            coalition_of=origin.coalition_robots,
            set_aside=(set_aside or {}).get(name, never_aside),
            clock=time.utc,
            monotonic=time.mono,
        )
        overlay = network.join(name, home, link)
        view = FederationView(name, store, link, overlay, clock=time.mono)
        reconciler = LoanReconciler(
            home, overlay, origin, view.lenders, clock=time.utc, monotonic=time.mono
        )
        out[name] = Cloud(name, store, link, home, overlay, view, origin, reconciler)
    return network, out


TASK = {
    "location": [0.0, 0.0],
    "actuating": {"grabber": 1},
    "max_robots": 1,
    "max_cost": 10.0,
    "max_time": 10.0,
}

StoreWrite = Callable[..., Awaitable[Any]]


async def _write_now(function: Callable[..., Any], *args: Any) -> Any:
    return function(*args)


def candidates_seen(
    cloud: Cloud, routes: RobotRoutes | None = None, store_write: StoreWrite = _write_now
) -> list[tuple[str, ...]]:
    """The candidates of a new request's selections at ``cloud``, by a request actor
    whose selector chooses none (the request then fails)."""
    record, _ = cloud.store.create_request("app", TASK)
    seen: list[tuple[str, ...]] = []

    async def in_thread(function: Callable[..., Any], *args: Any) -> Any:
        return await asyncio.to_thread(function, *args)

    async def selector(problem: Any, task: Task) -> Any:
        seen.append(tuple(problem.ids))
        return failed(len(problem.ids), 0.0, SelectorSettings(), "none chosen (test)")

    shell = Shell(
        store=cloud.store,
        view=cloud.view,
        selector=selector,
        rules=lc.Rules(),
        blocking=in_thread,
        store_write=store_write,
        publish=lambda _: None,
        routes=routes or RobotRoutes(),
    )
    life = lc.Life(record.id, Task.model_validate(TASK))
    asyncio.run(RequestActor(shell, life, record).run(lc.Start()))
    return seen
