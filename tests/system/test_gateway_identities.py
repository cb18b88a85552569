"""Gateways with a certificate of their own, written as the attacker would: gateway gw-1's.

cloud-a's IaaS runs on mutual TLS with ``--gateways`` naming gw-1 (fronting
a-0001 and a-0002) and gw-2 (fronting a-0003), each holding its own
certificate (``cloud-a-gateway-<name>``, from ``make-certs``). gw-2 is an
honest gateway: robocloud's own ``ZenohFleet`` (what ``robocloud vda5050``,
``nxt`` and ``ros2`` use) publishes a-0003's state in its batches and answers
a-0003's commands. The attacker holds gw-1's certificate: besides its own
robots, it puts a-0003's state in its own batch, on gw-2's batch key and on
a-0003's own key, and declares a-0003's command queryable and the wildcard
one. The router refuses what is on another gateway's keys (each refusal a
line in the IaaS's log and a count of ``robocloud_router_refusals``); the
IaaS drops the state of gw-1's batch that names a-0003, and tells a-0003 why
on its error key. a-0003 stays as gw-2 reports it, and its commands reach
gw-2 alone.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from processes import Cloud, wait_until
from secure_clouds import listed, repliers, robot_state, secure_cloud, session_as

from robocloud.federation.security.policy import gateway_name
from robocloud.fleet import keys
from robocloud.fleet.ingest import encode_batch
from robocloud.fleet.messages import Ack, Assign, Cancel, State
from robocloud.gateways.zenoh_side import ZenohFleet

pytestmark = pytest.mark.slow

CLOUD = "cloud-a"
GW1, GW2 = gateway_name(CLOUD, "gw-1"), gateway_name(CLOUD, "gw-2")


def state(robot: str, seq: int, position: list[float], battery: float = 90.0) -> State:
    return robot_state(CLOUD, robot, seq, position, battery)


def batch(*states: State) -> bytes:
    return encode_batch([s.model_dump(mode="json") for s in states])


@pytest.fixture(scope="module")
def cloud_a(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Cloud, Path]]:
    tmp_path = tmp_path_factory.mktemp("gateways")
    gateways = tmp_path / "gateways.txt"
    gateways.write_text("# cloud-a's gateways with a certificate of their own\n"
                        "gw-1 a-0001 a-0002\ngw-2 a-0003\n")  # fmt: skip
    with secure_cloud(tmp_path, CLOUD, [GW1, GW2], ["--gateways", str(gateways)]) as made:
        yield made


def test_a_gateway_certificate_speaks_for_its_robots_only(cloud_a: tuple[Cloud, Path]) -> None:
    cloud, certs = cloud_a
    honest = session_as(cloud, certs, GW2)
    attacker = session_as(cloud, certs, GW1)
    tool = session_as(cloud, certs, CLOUD)  # the IaaS's own certificate: asks as the IaaS does
    heard: list[tuple[str, str]] = []
    lock = threading.Lock()

    def on_command(robot: str, command: Assign | Cancel) -> Ack:
        with lock:
            heard.append((robot, command.type))
        return Ack(ok=True, robot=robot, request_id=command.request_id)

    errors: list[dict[str, Any]] = []
    told = tool.declare_subscriber(
        keys.error_key(CLOUD, "a-0003"),
        lambda sample: errors.append(json.loads(sample.payload.to_bytes())),
    )
    fleet = ZenohFleet(honest, CLOUD, "gw-2", on_command)
    try:
        # The honest gw-2: a-0003's state in its batch, a-0003's commands answered.
        fleet.add("a-0003")
        fleet.publish(state("a-0003", 1, [30.0, 30.0]))
        wait_until(
            lambda: listed(cloud).get("a-0003", {}).get("position") == [30.0, 30.0],
            20,
            "gw-2's a-0003 to be listed",
        )

        # The attacker, gw-1: a-0003 in its own batch, on gw-2's key and a-0003's own key.
        forged = state("a-0003", 2**40, [999.0, 999.0], battery=5.0)
        attacker.put(keys.batch_key(CLOUD, "gw-1"), batch(state("a-0001", 1, [1.0, 1.0]), forged))
        attacker.put(keys.batch_key(CLOUD, "gw-2"), batch(forged))
        attacker.put(keys.state_key(CLOUD, "a-0003"), forged.model_dump_json())
        forged_cmd = attacker.declare_queryable(
            keys.cmd_key(CLOUD, "a-0003"),
            lambda query: query.reply(query.key_expr, '{"ok": true}'),
        )
        wildcard = attacker.declare_queryable(
            keys.all_cmds(CLOUD), lambda query: query.reply(query.key_expr, '{"ok": true}')
        )
        # Its own robots, last: once the IaaS has them, the router judged the rest (one link).
        own = ZenohFleet(attacker, CLOUD, "gw-1", on_command)
        own.add("a-0002")
        own.publish(state("a-0002", 1, [2.0, 2.0]))
        wait_until(
            lambda: listed(cloud).get("a-0002", {}).get("position") == [2.0, 2.0],
            20,
            "gw-1's own a-0002 to be listed",
        )

        go = Assign(request_id="req-probe", location=[0.0, 0.0], capabilities=["kicker"])

        def ask(robot: str) -> list[str]:
            return repliers(tool, keys.cmd_key(CLOUD, robot), go.model_dump_json())

        wait_until(lambda: ask("a-0002"), 10, "gw-1 to answer its own robot's commands")
        assert ask("a-0003") == [str(honest.zid())]
        with lock:
            assert ("a-0003", "assign") in heard and ("a-0002", "assign") in heard

        robots = listed(cloud)
        assert robots["a-0003"]["position"] == [30.0, 30.0]
        assert robots["a-0003"]["battery"] == 90.0
        assert robots["a-0001"]["position"] == [1.0, 1.0]  # the rest of gw-1's batch is kept
        wait_until(lambda: errors, 10, "a-0003 to be told of the state gw-1 sent for it")
        assert errors[0]["field"] == "id" and "gateway gw-1 fronts" in errors[0]["error"]

        refused = {
            (GW1, "put"): 2.0,  # gw-2's batch key, a-0003's state key
            (GW1, "declare_queryable"): 2.0,  # a-0003's command key, the wildcard
        }
        wait_until(lambda: cloud.router_refusals() == refused, 10, "the refusals to be counted")
        for each in (forged_cmd, wildcard):
            each.undeclare()  # type: ignore[no-untyped-call]
        own.close()
    finally:
        fleet.close()
        told.undeclare()  # type: ignore[no-untyped-call]
        for session in (honest, attacker, tool):
            session.close()  # type: ignore[no-untyped-call]
    log = (cloud.workdir / f"{CLOUD}-iaas.log").read_text()
    said = [line for line in log.splitlines() if "router refused" in line]
    for key in (keys.batch_key(CLOUD, "gw-2"), keys.state_key(CLOUD, "a-0003")):
        assert any(repr(key) in line and GW1 in line for line in said), key
    assert "999" not in log
