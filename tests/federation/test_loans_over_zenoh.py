"""A thousand loans made and released between two clouds over real Zenoh routers.

The home keeps every loan findable, however many came before: the lookups
are indexed (the loans table by robot and by origin request), not a window
of the newest ones, so the oldest loan is released as surely as the newest.
How long they take at 10 and 1,000 loans is measured in
``benchmarks/federation.py``; this test checks counts and behaviour only.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import pytest
from federation_testing import zenoh_pair

from robocloud.domain import Robot
from robocloud.federation.home import Home
from robocloud.federation.messages import Dispatch, Release, Reservation
from robocloud.federation.overlay import ZenohOverlay
from robocloud.fleet import MemoryRobotLink
from robocloud.fleet.messages import Assign
from robocloud.storage import MemoryRequestStore, SqlRequestStore

pytestmark = pytest.mark.slow

LOANS = 1000


def robot(i: int) -> Robot:
    return Robot.model_validate(
        {
            "id": f"b-{i:04d}",
            "cloud": "cloud-b",
            "position": [float(i), 0.0],
            "speed": 1.0,
            "battery": 90.0,
            "status": "idle",
            "travel_cost_per_m": 0.1,
            "capabilities": {"grabber": {"kind": "actuating", "time": 20.0, "cost": 3.0}},
        }
    )


@pytest.fixture
def two_clouds(tmp_path: Path) -> Iterator[tuple[ZenohOverlay, Home]]:
    """cloud-a (no robots) and cloud-b (1,000 robots, a SQLite store), routers joined."""
    store = SqlRequestStore(f"sqlite:///{tmp_path / 'cloud-b.db'}")
    # Heard from throughout: they publish once, and a home lends only robots heard lately.
    link = MemoryRobotLink("cloud-b", [robot(i) for i in range(LOANS)], offline_after=3600)
    # No lease lapses during the test; every robot to one origin, as fast as it asks.
    home_b = Home("cloud-b", store, link, lease_max=3600, lend_share=1.0, reserve_rate=math.inf)
    home_a = Home("cloud-a", MemoryRequestStore(), MemoryRobotLink("cloud-a"))
    try:
        # The calls wait up to 5 s (1 s by default): the test counts loans, not time, and a
        # loaded machine (two test workers beside other work) can stall a call past 1 s.
        with zenoh_pair(home_a, home_b, timeout=5.0) as (a, _):
            yield a, home_b
    finally:
        store.close()


def test_a_thousand_loans_made_and_released(two_clouds: tuple[ZenohOverlay, Home]) -> None:
    a, home = two_clouds
    requests = [f"req-{i:04d}" for i in range(LOANS)]
    robots = [f"b-{i:04d}" for i in range(LOANS)]
    for i, (request_id, robot_id) in enumerate(zip(requests, robots, strict=True)):
        lease = Reservation(request_id=request_id, robots=[robot_id])
        assert a.reserve("cloud-b", lease).taken == []
        if i % 10 == 0:  # every tenth is dispatched and made firm
            go = Assign(request_id=request_id, location=[0.0, 0.0], capabilities=["grabber"])
            assert a.dispatch("cloud-b", Dispatch(robot=robot_id, command=go)).ok
            assert a.confirm("cloud-b", lease).taken == []
    assert len(home.store.loans()) == LOANS
    assert sum(loan.state == "firm" for loan in home.store.loans()) == LOANS // 10
    assert all(home.lent_for(r) == q for q, r in zip(requests, robots, strict=True)), (
        "every loan is known by its robot"
    )
    # The oldest loan is as reachable as the newest: dispatch both.
    for i in (0, LOANS - 1):
        go = Assign(request_id=requests[i], location=[0.0, 0.0], capabilities=["grabber"])
        assert a.dispatch("cloud-b", Dispatch(robot=robots[i], command=go)).ok
    # Released oldest first, each release ends exactly its loan.
    for i, (request_id, robot_id) in enumerate(zip(requests, robots, strict=True)):
        assert a.release("cloud-b", Release(request_id=request_id)).ok
        assert home.lent_for(robot_id) is None
        if i in (0, LOANS // 2):
            assert len(home.store.loans()) == LOANS - i - 1
    assert home.store.loans() == []
    assert home.store.reservations() == {}
