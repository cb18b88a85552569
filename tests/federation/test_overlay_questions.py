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
from federation_testing import robot, zenoh_pair

from robocloud.errors import RoboCloudError
from robocloud.federation.home import Home
from robocloud.federation.messages import Dispatch, IdleQuery
from robocloud.federation.overlay import ZenohOverlay
from robocloud.fleet import MemoryRobotLink
from robocloud.fleet.messages import Assign
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


@pytest.fixture
def clouds() -> Iterator[tuple[ZenohOverlay, FrozenRobots]]:
    home_b = FrozenRobots(
        "cloud-b",
        MemoryRequestStore(),
        MemoryRobotLink("cloud-b", [robot("cloud-b", i) for i in range(3)]),
    )
    home_a = Home("cloud-a", MemoryRequestStore(), MemoryRobotLink("cloud-a"))
    try:
        with zenoh_pair(home_a, home_b, timeout=20.0) as (a, _):
            yield a, home_b
            home_b.thaw.set()  # before the overlays close: their stuck threads end
    finally:
        home_b.thaw.set()


def test_a_home_answers_questions_while_its_commands_wait_on_robots(
    clouds: tuple[ZenohOverlay, FrozenRobots],
) -> None:
    a, home_b = clouds
    command = Assign(request_id="req-aaaaaaaaaaaa", location=[0.0, 0.0], capabilities=["grabber"])
    acks = []
    stuck = [
        threading.Thread(
            target=lambda: acks.append(
                a.dispatch("cloud-b", Dispatch(robot="b-0", command=command))
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
    assert sorted(r.id for r in gathered.replies["cloud-b"].robots) == ["b-0", "b-1", "b-2"]
    assert [info.cloud for info in a.infos()] == ["cloud-a", "cloud-b"]
    home_b.thaw.set()
    for thread in stuck:
        thread.join(20)
    assert len(acks) == STUCK and not any(ack.ok for ack in acks)
    assert "did not answer" in (acks[0].error or "")
