"""A home's questions are answered beside its commands, never behind them (real Zenoh routers).

A command may wait on robots (a dispatch waits for the robot's ack, up to the
ack timeout); a question (its idle robots, its info) waits on nothing. Found
by a fault walkthrough: with one cloud's simulator frozen, the other clouds'
commands to its robots filled the home's answering threads, and 25 selections
elsewhere left that cloud out ("did not answer within 500 ms").
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from typing import Any

import pytest
import zenoh
from federation_testing import free_endpoint, wait_for_commands

from robocloud.domain import Robot
from robocloud.errors import RoboCloudError
from robocloud.federation.keys import cloud_token
from robocloud.federation.messages import Dispatch, IdleQuery
from robocloud.federation.overlay import ZenohOverlay
from robocloud.fleet import MemoryRobotLink, open_router, wait_for_liveliness
from robocloud.fleet.messages import Assign
from robocloud.iaas.home import Home
from robocloud.storage import MemoryRequestStore

pytestmark = pytest.mark.slow

STUCK = 12  # commands waiting at once, more than the home answers at once


class FrozenRobots(Home):
    """A home whose robots do not answer: each dispatch waits until ``thaw``."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.thaw = threading.Event()
        self.waiting = threading.Semaphore(0)

    def dispatch(self, origin: str, dispatch: Dispatch) -> Any:
        self.waiting.release()
        self.thaw.wait(20)
        raise RoboCloudError(f"robot {dispatch.robot} did not answer.")


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
def clouds() -> Iterator[tuple[ZenohOverlay, FrozenRobots]]:
    b_endpoint = free_endpoint()
    b_session = open_router([b_endpoint])
    a_session = open_router([free_endpoint()], [b_endpoint])
    sessions: list[zenoh.Session] = [a_session, b_session]
    home_b = FrozenRobots("cloud-b", MemoryRequestStore(),
                          MemoryRobotLink("cloud-b", [robot(i) for i in range(3)]))
    home_a = Home("cloud-a", MemoryRequestStore(), MemoryRobotLink("cloud-a"))
    b = ZenohOverlay(b_session, "cloud-b", home_b)
    a = ZenohOverlay(a_session, "cloud-a", home_a, timeout=20.0)
    try:
        assert wait_for_liveliness(a_session, cloud_token("cloud-b"), 5.0)
        wait_for_commands(a, "cloud-b")
        yield a, home_b
    finally:
        home_b.thaw.set()
        a.close()
        b.close()
        for session in sessions:
            session.close()  # type: ignore[no-untyped-call]


def test_a_home_answers_questions_while_its_commands_wait_on_robots(
    clouds: tuple[ZenohOverlay, FrozenRobots],
) -> None:
    a, home_b = clouds
    command = Assign(request_id="req-aaaaaaaaaaaa", location=[0.0, 0.0],
                     capabilities=["grabber"])
    acks = []
    stuck = [
        threading.Thread(
            target=lambda: acks.append(
                a.dispatch("cloud-b", Dispatch(robot="b-0000", command=command))
            ),
            daemon=True,
        )
        for _ in range(STUCK)
    ]
    for thread in stuck:
        thread.start()
    # The home has taken commands until its threads for them are all waiting.
    for _ in range(4):
        assert home_b.waiting.acquire(timeout=10)
    query = IdleQuery(origin="cloud-a", min_battery=0.0, capabilities=["grabber"])
    gathered = a.gather_idle(query, 1.0)
    assert gathered.missing == []
    assert sorted(r.id for r in gathered.replies["cloud-b"].robots) == [
        "b-0000", "b-0001", "b-0002"
    ]
    assert [info.cloud for info in a.infos()] == ["cloud-a", "cloud-b"]
    home_b.thaw.set()
    for thread in stuck:
        thread.join(20)
    assert len(acks) == STUCK and not any(ack.ok for ack in acks)
    assert "did not answer" in (acks[0].error or "")
