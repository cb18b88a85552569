"""VDA 5050 fleets join a cloud: IaaS + simulator + gateway + Mosquitto + AGVs, all real processes.

The AGVs are VDA 5050 2.x vehicles written in the tests from the
specification (tests/gateways/vda5050_vehicle.py), one process each, on topics
of this run alone (the broker is shared). Every order and instant action they
receive is checked against the official JSON schemas.
"""

from __future__ import annotations

import datetime as dt
import json
import secrets
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
import pytest
from paho.mqtt.enums import CallbackAPIVersion
from processes import Cloud, follow, wait_until

pytestmark = pytest.mark.slow

ROOT = Path(__file__).parents[2]
VEHICLE = ROOT / "tests" / "gateways" / "vda5050_vehicle.py"
ACCEPT_WITHIN = 2.0  # the gateway's --accept-within here
# The AGVs drive 10 m/s (trips of 1.5 to 9 s here); the simulated robots run 1,000
# times faster than the clock (a kicker's trip across the forest, a second or two).
AGV_SPEED = 10.0
SPEEDUP = 1000.0
CAPABILITIES = {
    "capabilities": {"lift": {"kind": "actuating", "time": 1.0, "cost": 2.0, "action": "pick"}},
    "travel_cost_per_m": 0.01,
}


@dataclass
class Fleet:
    cloud: Cloud
    interface: str
    workdir: Path
    broker: tuple[str, int]
    gateway: subprocess.Popen[bytes] | None = None
    vehicles: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)

    def start_vehicle(self, serial: str, x: float, *options: str) -> None:
        self.vehicles[serial] = subprocess.Popen(
            [sys.executable, str(VEHICLE), "--interface", self.interface, "--serial", serial,
             "--host", self.broker[0], "--port", str(self.broker[1]),
             "--x", str(x), "--speed", str(AGV_SPEED), "--action-time", "0.5",
             "--log", str(self.log_of(serial)), *options],
            stdout=subprocess.DEVNULL, stderr=open(self.workdir / f"{serial}.err", "ab"),  # noqa: SIM115
        )  # fmt: skip

    def start_gateway(self) -> None:
        caps = self.workdir / "capabilities.json"
        caps.write_text(json.dumps(CAPABILITIES))
        self.gateway = subprocess.Popen(
            [sys.executable, "-m", "robocloud.cli.main", "vda5050", "--cloud", "cloud-a",
             "--connect", self.cloud.zenoh, "--mqtt", f"{self.broker[0]}:{self.broker[1]}",
             "--interface", self.interface, "--capabilities", str(caps),
             "--reconcile-grace", "1", "--accept-within", str(ACCEPT_WITHIN)],
            stdout=subprocess.DEVNULL,
            stderr=open(self.workdir / "gateway.log", "ab"),  # noqa: SIM115
        )  # fmt: skip

    def picks(self, request_id: str) -> dict[str, int]:
        """How many actions of ``request_id`` each AGV finished (their logs say)."""
        return {
            serial: n for serial in self.vehicles
            if (n := sum(str(r.get("did", "")).startswith(f"{request_id}.")
                         for r in self.received(serial)))
        }  # fmt: skip

    def log_of(self, serial: str) -> Path:
        return self.workdir / f"{serial}.jsonl"

    def received(self, serial: str) -> list[dict[str, Any]]:
        path = self.log_of(serial)
        if not path.exists():
            return []
        return [json.loads(line) for line in path.read_text().splitlines() if line]


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory, mosquitto: tuple[str, int]) -> Iterator[Fleet]:
    workdir = tmp_path_factory.mktemp("vda5050")
    cloud = Cloud("cloud-a", workdir, f"sqlite:///{workdir / 'cloud-a.db'}", robots=12,
                  speedup=SPEEDUP)  # fmt: skip
    fleet = Fleet(cloud, f"uagv-test-{secrets.token_hex(4)}", workdir, mosquitto)
    try:
        cloud.start()
        fleet.start_gateway()
        for i in range(4):
            fleet.start_vehicle(f"agv-{i}", 5.0 * i)
        with cloud.client() as client:
            wait_until(
                lambda: len([r for r in client.get("/v1/robots").json()
                             if r["id"].startswith("acme.") and r["capabilities"]]) == 4,
                20, "the four AGVs to join with their capabilities",
            )  # fmt: skip
        yield fleet
    finally:
        for process in [*fleet.vehicles.values(), fleet.gateway]:
            if process is not None and process.poll() is None:
                process.terminate()
        for process in [*fleet.vehicles.values(), fleet.gateway]:
            if process is not None:
                process.wait(10)
        cloud.stop()
        clear_retained(fleet)


def clear_retained(fleet: Fleet) -> None:
    client = mqtt.Client(CallbackAPIVersion.VERSION2)
    client.connect(*fleet.broker)
    client.loop_start()
    for serial in fleet.vehicles:
        topic = f"{fleet.interface}/v2/acme/{serial}/connection"
        client.publish(topic, b"", qos=1, retain=True).wait_for_publish(5)
    client.disconnect()
    client.loop_stop()


def details(request: dict[str, Any]) -> list[str]:
    return [h["detail"] or "" for h in request["history"]]


def vda_messages(fleet: Fleet, kind: str) -> list[dict[str, Any]]:
    return [
        r for s in fleet.vehicles for r in fleet.received(s) if r.get("topic", "").endswith(kind)
    ]


def test_a_request_served_by_agvs_and_simulated_robots_together_completes(fleet: Fleet) -> None:
    # The AGVs lift; idle simulated robots of this seed (a-0003, a-0011) kick.
    task = {
        "location": [30.0, 0.0],
        "actuating": {"lift": 2, "kicker": 1},
        "max_robots": 3,
        "max_cost": 100_000.0,
        "max_time": 100_000.0,
        "priority": "time",
    }
    with fleet.cloud.client() as client:
        rid = client.post("/v1/requests", json=task).json()["id"]
        done = follow(client, rid, lambda r: r["state"] in ("completed", "failed", "rejected"),
                      60, "the request to end")  # fmt: skip
    assert done["state"] == "completed", done
    robots = [a["robot"] for a in done["coalition"]]
    assert len([r for r in robots if r.startswith("acme.")]) == 2, robots
    assert len([r for r in robots if r.startswith("a-")]) == 1, robots
    orders = vda_messages(fleet, "/order")
    assert len(orders) == 2
    # Everything the gateway sent (factsheet requests too) keeps to the official schemas.
    every = [r for s in fleet.vehicles for r in fleet.received(s) if "topic" in r]
    assert any(r["message"]["actions"][0]["actionType"] == "factsheetRequest"
               for r in every if r["topic"].endswith("/instantActions"))  # fmt: skip
    assert [r["errors"] for r in every if r["errors"]] == []
    for order in orders:
        assert order["errors"] == [], order["errors"]
        assert order["message"]["orderId"].startswith(rid)
        end = order["message"]["nodes"][-1]
        assert end["nodePosition"]["x"] == 30.0
        assert [a["actionType"] for a in end["actions"]] == ["pick"]


def test_a_cancel_reaches_the_agv_as_cancel_order(fleet: Fleet) -> None:
    task = {"location": [400.0, 0.0], "actuating": {"lift": 1}, "max_robots": 1,
            "max_cost": 100_000.0, "max_time": 100_000.0, "priority": "time"}  # fmt: skip
    with fleet.cloud.client() as client:
        rid = client.post("/v1/requests", json=task).json()["id"]
        follow(client, rid, lambda r: r["state"] == "underway", 20, "underway")
        assert client.post(f"/v1/requests/{rid}/cancel").json()["state"] == "canceled"
    cancels = wait_until(
        lambda: [m for m in vda_messages(fleet, "/instantActions")
                 if m["message"]["actions"][0]["actionType"] == "cancelOrder"],
        10, "the AGV to get cancelOrder",
    )  # fmt: skip
    assert len(cancels) == 1
    assert cancels[0]["errors"] == []
    robot = cancels[0]["topic"].split("/")[3]
    with fleet.cloud.client() as client:
        wait_until(
            lambda: {r["id"]: r for r in client.get("/v1/robots").json()}[f"acme.{robot}"][
                "status"] == "idle",
            10, "the AGV to be idle",
        )  # fmt: skip


def test_an_agv_whose_connection_drops_is_failed_and_replaced(fleet: Fleet) -> None:
    task = {"location": [60.0, 0.0], "actuating": {"lift": 1}, "max_robots": 1,
            "max_cost": 100_000.0, "max_time": 100_000.0, "priority": "time"}  # fmt: skip
    with fleet.cloud.client() as client:
        rid = client.post("/v1/requests", json=task).json()["id"]
        underway = follow(client, rid, lambda r: r["state"] == "underway", 20, "underway")
        first = underway["coalition"][0]["robot"]
        serial = first.split(".", 1)[1]
        fleet.vehicles[serial].send_signal(signal.SIGKILL)  # the broker sends its last will
        fleet.vehicles[serial].wait(5)
        done = follow(client, rid, lambda r: r["state"] in ("completed", "failed"), 90, "the end")
    assert done["state"] == "completed", done
    history = details(done)
    assert any(f"robot {first} failed" in d for d in history), history
    assert any(f"robot {first} replaced by acme." in d for d in history), history
    assert done["coalition"][0]["robot"] != first


def cancel_orders(fleet: Fleet, serial: str) -> list[dict[str, Any]]:
    return [
        r for r in fleet.received(serial) if r.get("topic", "").endswith("/instantActions")
        and r["message"]["actions"][0]["actionType"] == "cancelOrder"
    ]  # fmt: skip


def test_a_gateway_killed_mid_order_and_restarted_leaves_one_agv_on_the_pick(fleet: Fleet) -> None:
    """Issue 24: after kill -9 and a restart the old AGV kept its order and a second did the
    same pick. Now the AGV found on an order the IaaS does not assign again gets cancelOrder."""
    # 120 m: the AGV chosen (at 60 m, where the last test left it) drives 6 s, long
    # after the gateway was killed and while it starts again.
    task = {"location": [120.0, 0.0], "actuating": {"lift": 1}, "max_robots": 1,
            "max_cost": 100_000.0, "max_time": 100_000.0, "priority": "time"}  # fmt: skip
    assert fleet.gateway is not None
    with fleet.cloud.client() as client:
        rid = client.post("/v1/requests", json=task).json()["id"]
        underway = follow(client, rid, lambda r: r["state"] == "underway", 20, "underway")
        first = underway["coalition"][0]["robot"].split(".", 1)[1]
        fleet.gateway.send_signal(signal.SIGKILL)
        fleet.gateway.wait(5)
        fleet.start_gateway()
        done = follow(client, rid, lambda r: r["state"] in ("completed", "failed"), 60, "the end")
    orders = [r for r in vda_messages(fleet, "/order") if r["message"]["orderId"].startswith(rid)]
    if len(orders) > 1 or done["state"] == "failed":
        # Re-planned, or (a restart slower than the IaaS's 5 s, all AGVs offline at once) no
        # replacement: either way the first AGV was told to drop its order before its pick.
        wait_until(lambda: cancel_orders(fleet, first), 10, "cancelOrder for the first AGV")
    picks = fleet.picks(rid)
    assert sum(picks.values()) == (1 if done["state"] == "completed" else 0), (picks, done)
    assert first not in picks or len(orders) == 1, (picks, first)


def test_a_replayed_old_state_is_ignored_and_the_request_completes(fleet: Fleet) -> None:
    task = {"location": [25.0, 0.0], "actuating": {"lift": 1}, "max_robots": 1,
            "max_cost": 100_000.0, "max_time": 100_000.0, "priority": "time"}  # fmt: skip
    heard: dict[str, bytes] = {}
    spy = mqtt.Client(CallbackAPIVersion.VERSION2)
    spy.on_message = lambda c, u, m: heard.setdefault(m.topic, bytes(m.payload))
    spy.connect(*fleet.broker)
    spy.subscribe(f"{fleet.interface}/v2/acme/+/state")
    spy.loop_start()
    try:
        alive = [s for s, p in fleet.vehicles.items() if p.poll() is None]
        wait_until(lambda: len(heard) >= len(alive), 5, "a state of each AGV")
        with fleet.cloud.client() as client:
            rid = client.post("/v1/requests", json=task).json()["id"]
            underway = follow(client, rid, lambda r: r["state"] == "underway", 20, "underway")
            serial = underway["coalition"][0]["robot"].split(".", 1)[1]
            topic = f"{fleet.interface}/v2/acme/{serial}/state"
            for _ in range(3):  # the AGV's own state from before the order, replayed
                spy.publish(topic, heard[topic], qos=1).wait_for_publish(5)
            done = follow(client, rid, lambda r: r["state"] in ("completed", "failed"), 30, "end")
    finally:
        spy.disconnect()
        spy.loop_stop()
    assert done["state"] == "completed", done
    assert fleet.picks(rid) == {serial: 1}


def test_an_agv_that_never_shows_its_order_is_replaced_within_the_documented_time(
    fleet: Fleet,
) -> None:
    fleet.start_vehicle("deaf", 60.0, "--ignore-orders")
    task = {"location": [60.0, 0.0], "actuating": {"lift": 1}, "max_robots": 1,
            "max_cost": 100_000.0, "max_time": 100_000.0, "priority": "time"}  # fmt: skip
    try:
        with fleet.cloud.client() as client:
            wait_until(
                lambda: any(r["id"] == "acme.deaf" and r["capabilities"]
                            for r in client.get("/v1/robots").json()),
                20, "the AGV that ignores orders to join",
            )  # fmt: skip
            rid = client.post("/v1/requests", json=task).json()["id"]
            underway = follow(client, rid, lambda r: r["state"] == "underway", 20, "underway")
            assert underway["coalition"][0]["robot"] == "acme.deaf"  # it is at the location
            done = follow(client, rid, lambda r: r["state"] in ("completed", "failed"), 40, "end")
    finally:
        fleet.vehicles["deaf"].terminate()
    assert done["state"] == "completed", done
    assert done["coalition"][0]["robot"] != "acme.deaf"
    failed = next(h for h in done["history"] if "robot acme.deaf failed" in (h["detail"] or ""))
    began = next(h for h in done["history"] if h["state"] == "underway")
    took = dt.datetime.fromisoformat(failed["at"]) - dt.datetime.fromisoformat(began["at"])
    # --accept-within, the gateway's tick and the IaaS's reading of the state.
    assert took.total_seconds() < ACCEPT_WITHIN + 1.5, took
    assert cancel_orders(fleet, "deaf")  # told to drop the order it may have kept


def test_a_frozen_agv_without_last_will_is_offline_within_three_state_intervals(
    fleet: Fleet,
) -> None:
    """SIGSTOP: no state, no last will (its keep-alive is a minute); its factsheet promises a
    state a second, so it is listed offline within 3 s (and the gateway's next publish)."""
    fleet.start_vehicle("frozen", 900.0, "--keepalive", "60")
    robot = "acme.frozen"
    process = fleet.vehicles["frozen"]
    with fleet.cloud.client() as client:

        def listed() -> dict[str, Any] | None:
            robots = {r["id"]: r for r in client.get("/v1/robots").json()}
            return robots.get(robot)

        def status() -> str | None:
            found = listed()
            return found["status"] if found is not None else None

        # Idle with its capabilities: the gateway has its factsheet, and so its
        # state interval (1 s); before it, the default of 10 s would hold.
        wait_until(
            lambda: (found := listed()) is not None
            and found["status"] == "idle"
            and found["capabilities"],
            20,
            "the AGV to join with its factsheet",
        )
        process.send_signal(signal.SIGSTOP)
        try:
            stopped = time.monotonic()
            wait_until(lambda: status() == "offline", 10, "the frozen AGV to be offline")
            took = time.monotonic() - stopped
        finally:
            process.send_signal(signal.SIGCONT)
        wait_until(lambda: status() == "idle", 10, "the AGV to be back")
    assert took < 3.0 + 1.5, took
