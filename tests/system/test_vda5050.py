"""VDA 5050 fleets join a cloud: IaaS + simulator + gateway + Mosquitto + AGVs, all real processes.

The AGVs are VDA 5050 2.x vehicles written in the tests from the
specification (tests/gateways/vda5050_vehicle.py), one process each, on topics
of this run alone (the broker is shared). Every order and instant action they
receive is checked against the official JSON schemas.
"""

from __future__ import annotations

import json
import secrets
import signal
import subprocess
import sys
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

    def start_vehicle(self, serial: str, x: float) -> None:
        self.vehicles[serial] = subprocess.Popen(
            [sys.executable, str(VEHICLE), "--interface", self.interface, "--serial", serial,
             "--host", self.broker[0], "--port", str(self.broker[1]),
             "--x", str(x), "--speed", "5", "--action-time", "0.5",
             "--log", str(self.log_of(serial))],
            stdout=subprocess.DEVNULL, stderr=open(self.workdir / f"{serial}.err", "ab"),  # noqa: SIM115
        )  # fmt: skip

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
                  speedup=100.0)  # fmt: skip
    fleet = Fleet(cloud, f"uagv-test-{secrets.token_hex(4)}", workdir, mosquitto)
    caps = workdir / "capabilities.json"
    caps.write_text(json.dumps(CAPABILITIES))
    try:
        cloud.start()
        fleet.gateway = subprocess.Popen(
            [sys.executable, "-m", "robocloud.cli.main", "vda5050", "--cloud", "cloud-a",
             "--connect", cloud.zenoh, "--mqtt", f"{mosquitto[0]}:{mosquitto[1]}",
             "--interface", fleet.interface, "--capabilities", str(caps)],
            stdout=subprocess.DEVNULL, stderr=open(workdir / "gateway.log", "ab"),  # noqa: SIM115
        )  # fmt: skip
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
    return [r for s in fleet.vehicles for r in fleet.received(s) if r["topic"].endswith(kind)]


def test_a_request_served_by_agvs_and_simulated_robots_together_completes(fleet: Fleet) -> None:
    # The AGVs lift; idle simulated robots of this seed (a-0003, a-0011) kick.
    task = {"location": [30.0, 0.0], "actuating": {"lift": 2, "kicker": 1},
            "max_robots": 3, "max_cost": 100_000.0, "max_time": 100_000.0, "priority": "time"}
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
    every = [r for s in fleet.vehicles for r in fleet.received(s)]
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
