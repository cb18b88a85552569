"""The gateway in this process against the real Mosquitto and a real Zenoh router.

The IaaS side is a ZenohRobotLink on the router; the AGVs are test vehicles
written from the specification (vda5050_vehicle.py).
"""

from __future__ import annotations

import json
import logging
import time
import urllib.request
from collections.abc import Callable, Iterator
from typing import Any

import paho.mqtt.client as mqtt
import pytest
import zenoh
from paho.mqtt.enums import CallbackAPIVersion
from vda5050_testing import vda_state
from vda5050_vehicle import Vehicle

import loopback_ports
from robocloud.fleet import Assign, ZenohRobotLink, open_client, open_router
from robocloud.gateways.vda5050.agv import Timing
from robocloud.gateways.vda5050.capabilities import GatewayCapabilities
from robocloud.gateways.vda5050.gateway import Vda5050Gateway
from robocloud.gateways.vda5050.metrics import serve_metrics
from robocloud.gateways.zenoh_side import (
    CommandHandler,
    RobotSide,
    ZenohFleet,
    ZenohRobots,
)

pytestmark = pytest.mark.slow

CAPS = GatewayCapabilities.model_validate(
    {"capabilities": {"lift": {"kind": "actuating", "time": 1.0, "cost": 2.0, "action": "pick"}}}
)


def wait_until(predicate: Callable[[], Any], timeout: float = 10.0) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError("timed out")


# The gateway's times, shortened so the tests take seconds (the rules are the same).
TIMING = Timing(accept_within=1.5, reconcile_grace=1.5)
World = tuple[ZenohRobotLink, Vda5050Gateway, list[Vehicle]]


@pytest.fixture
def zenoh_side(free_port: int) -> Iterator[tuple[ZenohRobotLink, zenoh.Session]]:
    """A router with the IaaS's link on it, and the client session a gateway uses."""
    endpoint = f"tcp/127.0.0.1:{free_port}"
    router = open_router([endpoint])
    link = ZenohRobotLink(router, "cloud-a", command_timeout=2.0)
    session = open_client([endpoint], timeout=5.0)
    yield link, session
    session.close()  # type: ignore[no-untyped-call]
    link.close()
    router.close()  # type: ignore[no-untyped-call]


@pytest.fixture
def make_gateway(
    zenoh_side: tuple[ZenohRobotLink, zenoh.Session], mosquitto: tuple[str, int], interface: str
) -> Iterator[Callable[..., Vda5050Gateway]]:
    """Start a gateway (another one after a restart, say); each is stopped at the end."""
    _, session = zenoh_side
    started: list[Vda5050Gateway] = []

    def make(fleet: bool = False, timing: Timing = TIMING) -> Vda5050Gateway:
        def robot_side(on_command: CommandHandler) -> RobotSide:
            # "fleet": the AGVs behind one wildcard queryable, their states in batches.
            if fleet:
                return ZenohFleet(session, "cloud-a", "vda", on_command)
            return ZenohRobots(session, "cloud-a", on_command)

        gateway = Vda5050Gateway(robot_side, *mosquitto, CAPS, interface=interface, timing=timing)
        gateway.start()
        started.append(gateway)
        return gateway

    yield make
    for gateway in started:
        if gateway.running:
            gateway.stop()


@pytest.fixture
def world(
    zenoh_side: tuple[ZenohRobotLink, zenoh.Session],
    make_gateway: Callable[..., Vda5050Gateway],
    mosquitto: tuple[str, int],
    interface: str,
    request: pytest.FixtureRequest,
) -> Iterator[World]:
    link, _ = zenoh_side
    gateway = make_gateway(fleet=getattr(request, "param", "robots") == "fleet")
    vehicles: list[Vehicle] = []
    yield link, gateway, vehicles
    for vehicle in vehicles:
        vehicle.close()
    clear_retained(mosquitto, interface, vehicles)


def clear_retained(broker: tuple[str, int], interface: str, vehicles: list[Vehicle]) -> None:
    client = mqtt.Client(CallbackAPIVersion.VERSION2)
    client.connect(*broker)
    client.loop_start()
    for vehicle in vehicles:
        client.publish(f"{vehicle.base}/connection", b"", qos=1, retain=True).wait_for_publish(5)
    client.disconnect()
    client.loop_stop()


@pytest.fixture
def free_port() -> int:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
    return port


def join(world: World, interface: str,
         serial: str, x: float, **kw: Any) -> tuple[str, Vehicle]:  # fmt: skip
    link, gateway, vehicles = world
    vehicle = Vehicle(interface, "acme", serial, (x, 0.0), ["pick"], host=gateway.host,
                      port=gateway.port, **kw)  # fmt: skip
    vehicles.append(vehicle)
    robot = f"acme.{serial}"
    wait_until(lambda: robot in link.states() and link.states()[robot].capabilities)
    return robot, vehicle


@pytest.mark.parametrize("world", ["robots", "fleet"], indirect=True)
def test_an_agv_joins_takes_a_task_and_finishes_it(world: World, interface: str) -> None:
    link, gateway, _ = world
    robot, vehicle = join(world, interface, "agv-1", 0.0, speed=40.0)
    state = link.states()[robot]
    assert state.status == "idle" and state.position == [0.0, 0.0] and state.battery == 90.0
    assert state.kind == "test-agv" and state.speed == 40.0
    assert set(state.capabilities) == {"lift"}
    go = Assign(request_id="req-1", location=[20.0, 0.0], capabilities=["lift"])
    ack = link.assign(robot, go)
    assert ack.ok, ack
    orders = [r for r in vehicle.received if r["topic"].endswith("/order")]
    assert len(orders) == 1 and orders[0]["errors"] == []
    end = orders[0]["message"]["nodes"][1]
    assert end["nodePosition"] == {"x": 20.0, "y": 0.0, "mapId": "floor-1"}
    assert [a["actionType"] for a in end["actions"]] == ["pick"]
    phases: list[str] = []
    link.on_state(lambda s: phases.append(s.task.phase) if s.id == robot and s.task else None)
    done = wait_until(
        lambda: (s := link.states()[robot]).last_task is not None and s.last_task.phase == "done"
    )
    assert done
    final = link.states()[robot]
    assert final.position == [20.0, 0.0] and final.status == "idle"
    assert "work" in phases
    assert [r["errors"] for r in vehicle.received if r["errors"]] == []
    assert any(r["topic"].endswith("/instantActions") for r in vehicle.received)  # factsheet
    assert all(topic.endswith(("/order", "/instantActions")) for topic, _ in gateway.sent)


def test_a_cancel_reaches_the_agv_as_cancel_order(world: World, interface: str) -> None:
    link, _, _ = world
    robot, vehicle = join(world, interface, "agv-2", 0.0, speed=2.0)
    assert link.assign(robot, Assign(request_id="req-2", location=[50.0, 0.0],
                                     capabilities=["lift"])).ok  # fmt: skip
    wait_until(lambda: (t := link.states()[robot].task) is not None and t.phase == "travel")
    # A repeated assign is ok and sends no second order.
    assert link.assign(robot, Assign(request_id="req-2", location=[50.0, 0.0],
                                     capabilities=["lift"])).ok  # fmt: skip
    assert sum(r["topic"].endswith("/order") for r in vehicle.received) == 1
    ack = link.cancel(robot, "req-2")
    assert ack.ok, ack
    wait_until(lambda: any(r["topic"].endswith("/instantActions")
                           and r["message"]["actions"][0]["actionType"] == "cancelOrder"
                           for r in vehicle.received))  # fmt: skip
    cancel = next(r for r in vehicle.received if r["topic"].endswith("/instantActions")
                  and r["message"]["actions"][0]["actionType"] == "cancelOrder")  # fmt: skip
    assert cancel["errors"] == []
    wait_until(lambda: link.states()[robot].task is None and link.states()[robot].status == "idle")
    assert not vehicle.driving
    # Cancelling again is harmless; another request's cancel too.
    assert link.cancel(robot, "req-2").ok


def test_refusals_and_a_broken_connection(world: World, interface: str) -> None:
    link, _, _ = world
    robot, vehicle = join(world, interface, "agv-3", 0.0, speed=1.0)
    weld = link.assign(robot, Assign(request_id="req-3", location=[5.0, 0.0],
                                     capabilities=["weld"]))  # fmt: skip
    assert not weld.ok and weld.error == "AGV acme.agv-3 lacks the capability weld."
    assert link.assign(robot, Assign(request_id="req-3", location=[50.0, 0.0],
                                     capabilities=["lift"])).ok  # fmt: skip
    busy = link.assign(robot, Assign(request_id="req-4", location=[5.0, 0.0],
                                     capabilities=["lift"]))  # fmt: skip
    assert busy.error == "AGV acme.agv-3 is busy with request req-3."
    # The connection drops without a word: the broker sends the last will.
    vehicle.drop()
    failed = wait_until(
        lambda: (s := link.states()[robot]).status == "offline" and s.last_task is not None
    )
    assert failed
    last = link.states()[robot].last_task
    assert last is not None and last.request_id == "req-3" and last.phase == "failed"


def test_bad_and_partial_messages_are_logged_and_never_stop_the_gateway(
    world: World,
    interface: str,
    mosquitto: tuple[str, int],
    caplog: pytest.LogCaptureFixture,
) -> None:
    link, _, _ = world
    caplog.set_level(logging.WARNING)
    client = mqtt.Client(CallbackAPIVersion.VERSION2)
    client.connect(*mosquitto)
    client.loop_start()
    base = f"{interface}/v2/acme"
    partial = vda_state()
    del partial["batteryState"]
    too_full = vda_state(batteryState={"batteryCharge": 150, "charging": False})
    sends = [
        (f"{base}/bad-1/state", b"{not json"),
        (f"{base}/bad-2/state", json.dumps(partial).encode()),
        (f"{base}/bad-3/state", json.dumps(too_full).encode()),
        (f"{base}/bad-4/connection", json.dumps({"connectionState": "MAYBE"}).encode()),
        (f"{base}/bad-5/factsheet", json.dumps({"protocolFeatures": 3}).encode()),
        (f"{base}/bad$6/state", json.dumps(vda_state()).encode()),
        (f"{base}/bad-7/state", b"x" * 1_100_000),
    ]
    for topic, payload in sends:
        client.publish(topic, payload, qos=1).wait_for_publish(5)
    client.disconnect()
    client.loop_stop()
    robot, _ = join(world, interface, "agv-4", 0.0)  # the gateway still works
    assert link.assign(robot, Assign(request_id="req-5", location=[1.0, 0.0],
                                     capabilities=["lift"])).ok  # fmt: skip
    said = "\n".join(r.getMessage() for r in caplog.records)
    assert "bad-1/state: the input is not valid JSON" in said
    assert "bad-2/state: state.batteryState is missing." in said
    assert "bad-3/state: batteryState.batteryCharge is 150, not a percent from 0 to 100." in said
    assert "bad-4/connection: connection.connectionState: input should be" in said
    assert "bad-5/factsheet: factsheet.protocolFeatures" in said
    assert "acme.bad$6 cannot be a robot id" in said
    assert "bad-7/state: it is 1100000 bytes, over the 1048576 accepted." in said
    assert set(link.states()) == {robot}


def test_two_agvs_whose_names_make_one_robot_id_are_not_one_robot(
    world: World,
    interface: str,
    mosquitto: tuple[str, int],
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Manufacturer "dup" with serial "x.1" and "dup.x" with "1" are both dup.x.1: the
    second was taken as the same robot, its states mixed with the first's (found by hand)."""
    link, gateway, _ = world
    caplog.set_level(logging.WARNING)
    client = mqtt.Client(CallbackAPIVersion.VERSION2)
    client.connect(*mosquitto)
    client.loop_start()
    first = vda_state(
        agvPosition={
            "x": 200.0,
            "y": 0.0,
            "theta": 0.0,
            "mapId": "map",
            "positionInitialized": True,
        }
    )
    second = vda_state(
        agvPosition={
            "x": 300.0,
            "y": 0.0,
            "theta": 0.0,
            "mapId": "map",
            "positionInitialized": True,
        }
    )
    client.publish(f"{interface}/v2/dup/x.1/state", json.dumps(first), qos=1).wait_for_publish(5)
    wait_until(lambda: "dup.x.1" in link.states())
    for _ in range(3):
        client.publish(f"{interface}/v2/dup.x/1/state", json.dumps(second),
                       qos=1).wait_for_publish(5)  # fmt: skip
    # A third AGV's state, sent after the second's on the same connection: the
    # broker hands them on in order and the gateway takes them in order, so once
    # the IaaS hears the third robot, the gateway has handled the second's states
    # and published whatever they changed, in the same pass or before.
    marker = vda_state(manufacturer="mark", serialNumber="1")
    client.publish(f"{interface}/v2/mark/1/state", json.dumps(marker), qos=1).wait_for_publish(5)
    client.disconnect()
    client.loop_stop()
    wait_until(lambda: "mark.1" in link.states())
    assert any("which the AGV dup/x.1 is already" in r.getMessage() for r in caplog.records)
    assert gateway.robot_ids() == ["dup.x.1", "mark.1"]
    assert link.states()["dup.x.1"].position == [200.0, 0.0]


# -- the AGV's word, checked (issue 24) ---------------------------------------------------


def cancel_orders(vehicle: Vehicle) -> list[dict[str, Any]]:
    return [
        r for r in vehicle.received if r["topic"].endswith("/instantActions")
        and r["message"]["actions"][0]["actionType"] == "cancelOrder"
    ]  # fmt: skip


def publish(broker: tuple[str, int], topic: str, message: dict[str, Any], times: int = 1) -> None:
    client = mqtt.Client(CallbackAPIVersion.VERSION2)
    client.connect(*broker)
    client.loop_start()
    for _ in range(times):
        client.publish(topic, json.dumps(message), qos=1).wait_for_publish(5)
    client.disconnect()
    client.loop_stop()


def test_a_replayed_old_state_is_ignored_and_the_request_completes(
    world: World, interface: str, mosquitto: tuple[str, int]
) -> None:
    link, gateway, _ = world
    robot, vehicle = join(world, interface, "agv-5", 0.0, speed=20.0)
    old = vehicle.state()  # no order in it: taken as new, it would say the order was dropped
    assert link.assign(robot, Assign(request_id="req-6", location=[20.0, 0.0],
                                     capabilities=["lift"])).ok  # fmt: skip
    wait_until(lambda: link.states()[robot].position[0] > 0.0)  # the order is under way
    publish(mosquitto, f"{vehicle.base}/state", old, times=3)
    wait_until(lambda: gateway.numbers().stale == 3)
    done = wait_until(
        lambda: (s := link.states()[robot]).last_task is not None and s.last_task.phase == "done"
    )
    assert done
    assert vehicle.did == ["req-6.1-lift"] and cancel_orders(vehicle) == []


def test_an_order_the_agv_never_shows_is_cancelled_and_its_task_fails_with_a_reason(
    world: World, interface: str
) -> None:
    link, gateway, _ = world
    robot, vehicle = join(world, interface, "agv-6", 0.0, ignore_orders=True)
    sent = time.monotonic()
    ack = link.assign(robot, Assign(request_id="req-7", location=[20.0, 0.0],
                                    capabilities=["lift"]))  # fmt: skip
    assert ack.ok  # nothing against it within a second: the ack does not wait for the state
    failed = wait_until(
        lambda: (s := link.states()[robot]).last_task is not None and s.last_task.phase == "failed"
    )
    assert failed
    assert time.monotonic() - sent < TIMING.accept_within + 1.0  # the documented bound, and a tick
    last = link.states()[robot].last_task
    assert last is not None and last.reason == (
        "AGV acme.agv-6: the AGV did not show the order req-7.1 (orderUpdateId 0) in its state "
        "within 1.5 s."
    )
    cancel = wait_until(lambda: cancel_orders(vehicle))
    assert cancel[0]["errors"] == []
    port = loopback_ports.free_port()
    serve_metrics(gateway, "127.0.0.1", port)
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as answer:
        scraped = answer.read().decode()
    assert "robocloud_vda5050_orders_not_accepted_total 1.0" in scraped
    assert "robocloud_vda5050_stale_states_total 0.0" in scraped
    assert 'robocloud_vda5050_agvs{status="idle"} 1.0' in scraped


STATE_EVERY = 0.3  # seconds: the frozen AGV's state interval (its factsheet's)


def test_a_frozen_agv_without_last_will_is_offline_within_three_state_intervals(
    world: World, interface: str
) -> None:
    link, _, _ = world
    robot, vehicle = join(world, interface, "agv-7", 0.0, speed=1.0, state_interval=STATE_EVERY)
    assert link.assign(robot, Assign(request_id="req-8", location=[50.0, 0.0],
                                     capabilities=["lift"])).ok  # fmt: skip
    wait_until(lambda: link.states()[robot].position[0] > 0.0)
    heard: list[float] = []
    vehicle.freeze()
    frozen, frozen_wall = time.monotonic(), time.time()
    link.on_state(lambda s: heard.append(s.sent_at) if s.id == robot else None)
    offline = wait_until(lambda: link.states()[robot].status == "offline", 10.0)
    assert offline
    # Its factsheet says a state every 0.3 s: silent for three of them is offline (and a
    # tick, a publish).
    assert time.monotonic() - frozen < 3 * STATE_EVERY + 1.5
    state = link.states()[robot]
    assert state.sent_at <= frozen_wall  # the AGV's own last word, however often re-published
    assert heard and max(heard) <= frozen_wall
    last = state.last_task
    assert last is not None and last.phase == "failed" and last.reason is not None
    assert "the AGV has been silent for" in last.reason
    assert f"over the {3 * STATE_EVERY:g} s allowed" in last.reason


def test_after_a_restart_an_order_is_cancelled_unless_the_iaas_assigns_it_again(
    world: World, interface: str, make_gateway: Callable[..., Vda5050Gateway]
) -> None:
    link, gateway, _ = world
    dropped, lost = join(world, interface, "agv-8", 0.0, speed=1.0)
    kept, found = join(world, interface, "agv-9", 100.0, speed=4.0)
    mine = Assign(request_id="req-9", location=[50.0, 0.0], capabilities=["lift"])
    theirs = Assign(request_id="req-10", location=[110.0, 0.0], capabilities=["lift"])
    assert link.assign(dropped, mine).ok and link.assign(kept, theirs).ok
    wait_until(lambda: lost.order_id == "req-9.1" and found.order_id == "req-10.1")
    gateway.stop()  # as a kill: the AGVs hear nothing
    stopped = time.time()
    again = make_gateway()
    # The new gateway's first state of agv-9 shows the order it found.
    wait_until(lambda: link.states()[kept].sent_at > stopped)
    assert link.states()[kept].task is not None
    assert link.assign(kept, theirs).ok  # the IaaS assigns req-10 again within the grace
    cancel = wait_until(lambda: cancel_orders(lost), 5.0)
    assert cancel[0]["errors"] == []
    last = wait_until(lambda: link.states()[dropped].last_task)
    assert last.request_id == "req-9" and last.phase == "failed"
    assert "did not assign request req-9 to it again within 1.5 s" in str(last.reason)
    done = wait_until(
        lambda: (s := link.states()[kept]).last_task is not None and s.last_task.phase == "done"
    )
    assert done
    assert found.did == ["req-10.1-lift"] and lost.did == []
    assert cancel_orders(found) == []
    assert sum(r["topic"].endswith("/order") for r in found.received) == 1  # no second order
    assert again.numbers().reconcile_cancels >= 1
