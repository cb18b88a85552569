"""Fleet gateways on a real loopback Zenoh network: batches of states, one queryable for many.

One simulator as a gateway (its robots' states in batches, one wildcard
command queryable) and one robot of its own (per-robot keys) share a cloud:
the IaaS's link sees them all, and each command reaches the right robot.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
import zenoh
from fleet_testing import until_subscribed

from loopback_ports import free_endpoint
from robocloud.errors import InvalidInput
from robocloud.fleet import Ack, Assign, ZenohRobotLink, keys, open_client, open_router
from robocloud.fleet.messages import State
from robocloud.sim.fleet import FleetSimulator
from robocloud.sim.roster import cloud_robots
from waiting import wait_until

CLOUD = "cloud-g"
FLEET = 40
NOW = time.time()


@pytest.fixture(autouse=True)
def _states_of_now() -> None:
    """Each test's states are sent now: within the IaaS's clock bound (300 s), however
    long after the module's import the test runs (a full suite takes minutes)."""
    global NOW
    NOW = time.time()


def state(robot_id: str, seq: int = 1, **changes: Any) -> dict[str, Any]:
    fields: dict[str, Any] = {
        "id": robot_id,
        "cloud": CLOUD,
        "kind": "tribot",
        "position": [0.0, 0.0],
        "speed": 1.0,
        "battery": 90.0,
        "status": "idle",
        "travel_cost_per_m": 0.05,
        "capabilities": {"grabber": {"kind": "actuating", "time": 60.0, "cost": 8.0}},
        "task": None,
        "seq": seq,
        "sent_at": NOW + seq,  # within the IaaS's clock skew bound
    }
    fields.update(changes)
    return fields


class LoneRobot:
    """A robot of its own on per-robot keys, answering every command ok."""

    def __init__(self, session: zenoh.Session, robot_id: str) -> None:
        self.id = robot_id
        self.commands: list[dict[str, Any]] = []
        self._session = session
        self._queryable = session.declare_queryable(keys.cmd_key(CLOUD, robot_id), self._on)

    def _on(self, query: zenoh.Query) -> None:
        with query:
            assert query.payload is not None
            command = json.loads(query.payload.to_bytes())
            self.commands.append(command)
            ack = Ack(ok=True, robot=self.id, request_id=command["request_id"])
            query.reply(keys.cmd_key(CLOUD, self.id), ack.model_dump_json())

    def report(self) -> None:
        self._session.put(keys.state_key(CLOUD, self.id), json.dumps(state(self.id)))

    def close(self) -> None:
        self._queryable.undeclare()  # type: ignore[no-untyped-call]


@pytest.fixture(scope="module")
def cloud() -> Iterator[tuple[zenoh.Session, zenoh.Session, ZenohRobotLink, FleetSimulator]]:
    endpoint = free_endpoint()
    router = open_router([endpoint])
    client = open_client([endpoint])
    link = ZenohRobotLink(router, CLOUD, command_timeout=2.0)
    simulator = FleetSimulator(
        CLOUD, cloud_robots(CLOUD, FLEET, seed=3), client, gateway="sim-1", batch_size=7
    )
    simulator.start()
    yield router, client, link, simulator
    simulator.stop()
    link.close()
    client.close()  # type: ignore[no-untyped-call]
    router.close()  # type: ignore[no-untyped-call]


def test_the_iaas_sees_a_gateways_robots_and_a_lone_robot_and_commands_reach_each(
    cloud: tuple[zenoh.Session, zenoh.Session, ZenohRobotLink, FleetSimulator],
) -> None:
    _, client, link, simulator = cloud
    lone = LoneRobot(client, "g-lone")
    try:
        assert wait_until(lambda: len(link.states()) >= FLEET, timeout=10)
        # A robot reports at least once a second (docs/protocol.md): so does this one
        # until the link has it.
        assert wait_until(lambda: lone.report() or "g-lone" in link.states(), 10, every=0.2)
        assert set(link.states()) == {*simulator.robot_ids, "g-lone"}
        assert link.count() == FLEET + 1
        assert [r.id for r in link.robots()] == sorted(link.states())

        # A robot behind the gateway: only the gateway answers, for that robot.
        chosen = max(
            (s for s in link.states().values() if s.status == "idle" and s.id != "g-lone"),
            key=lambda s: s.battery,
        )
        target = chosen.id
        go = Assign(
            request_id="r-g1",
            location=[chosen.position[0] + 1.0, chosen.position[1]],
            capabilities=[next(iter(chosen.capabilities))],
        )
        ack = link.assign(target, go)
        assert ack == Ack(ok=True, robot=target, request_id="r-g1"), ack
        assert wait_until(lambda: _task_of(link.state(target)) == "r-g1", timeout=5)
        assert lone.commands == []

        # The lone robot: its own queryable answers; the gateway stays silent.
        ack = link.assign("g-lone", go)
        assert ack == Ack(ok=True, robot="g-lone", request_id="r-g1")
        assert lone.commands == [json.loads(go.model_dump_json())]
        assert link.cancel(target, "r-g1").ok
        # A robot nobody fronts: no answer from anyone.
        assert link.assign("g-nobody", go).unanswered
    finally:
        lone.close()


def _task_of(state: State | None) -> str | None:
    return state.task.request_id if state is not None and state.task is not None else None


def test_a_bad_state_in_a_batch_gets_its_robot_an_error_and_keeps_the_others(
    cloud: tuple[zenoh.Session, zenoh.Session, ZenohRobotLink, FleetSimulator],
) -> None:
    router, client, link, _ = cloud
    answers: dict[str, dict[str, Any]] = {}
    lock = threading.Lock()

    def heard(sample: zenoh.Sample) -> None:
        with lock:
            answers[str(sample.key_expr)] = json.loads(sample.payload.to_bytes())

    listening = client.declare_subscriber(f"robocloud/{CLOUD}/robots/*/error", heard)
    until_subscribed(router, f"robocloud/{CLOUD}/robots/m-2/error")
    try:
        other_cloud = state("m-3", cloud="cloud-x")
        batch = [state("m-1"), state("m-2", battery=150.0), state("m-4"), other_cloud]
        client.put(keys.batch_key(CLOUD, "manual"), json.dumps(batch))
        assert wait_until(lambda: len(answers) == 2)
        assert wait_until(lambda: {"m-1", "m-4"} <= set(link.states()))
        assert "m-2" not in link.states() and "m-3" not in link.states()
        refused = answers[keys.error_key(CLOUD, "m-2")]
        assert refused["field"] == "battery"
        assert refused["error"] == "battery: input should be less than or equal to 100."
        assert refused["robot"] == "m-2"
        assert answers[keys.error_key(CLOUD, "m-3")]["field"] == "cloud"
        # Not an array at all: nobody to answer, nothing taken, nothing broken.
        client.put(keys.batch_key(CLOUD, "manual"), b'{"id": "m-9"}')
        client.put(keys.batch_key(CLOUD, "manual"), json.dumps([state("m-5")]))
        assert wait_until(lambda: "m-5" in link.states())
        assert "m-9" not in link.states()
    finally:
        listening.undeclare()  # type: ignore[no-untyped-call]


def test_a_gateway_needs_a_key_chunk_and_a_sane_batch_size() -> None:
    robots = cloud_robots(CLOUD, 2, seed=0)
    with pytest.raises(InvalidInput, match="gateway"):
        FleetSimulator(CLOUD, robots, session=None, gateway="a/b")  # type: ignore[arg-type]
    with pytest.raises(InvalidInput, match="batch_size"):
        FleetSimulator(CLOUD, robots, session=None, gateway="g", batch_size=0)  # type: ignore[arg-type]
    assert keys.batch_key(CLOUD, "g") == "robocloud/cloud-g/fleets/g/states"
    assert keys.all_batches(CLOUD) == "robocloud/cloud-g/fleets/*/states"


def test_another_cloud_follows_a_borrowed_robot_behind_a_gateway(
    cloud: tuple[zenoh.Session, zenoh.Session, ZenohRobotLink, FleetSimulator],
) -> None:
    from robocloud.federation.home import Home
    from robocloud.federation.overlay import ZenohOverlay
    from robocloud.fleet import MemoryRobotLink
    from robocloud.storage import MemoryRequestStore

    router, _, _, simulator = cloud
    home = Home("cloud-w", MemoryRequestStore(), MemoryRobotLink("cloud-w"))
    overlay = ZenohOverlay(router, "cloud-w", home)
    try:
        borrowed = simulator.robot_ids[3]
        overlay.watch(CLOUD, borrowed)
        assert wait_until(lambda: borrowed in overlay.states(), timeout=5)
        assert set(overlay.states()) == {borrowed}  # only the watched one of the batches
        overlay.unwatch(CLOUD, borrowed)
    finally:
        overlay.close()
