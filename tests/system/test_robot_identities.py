"""Per-robot identities, written as the attacker would: robot a-0001's own certificate.

cloud-a's IaaS runs on mutual TLS with ``--robot-ids`` naming a-0001 and
a-0002, each holding its own certificate (``cloud-a-robot-<id>``, from
``make-certs``). a-0002 is a real robot: it puts its state and answers its
command key. The attacker holds a-0001's certificate and, besides its own
state, puts a state for a-0002 (and a batch, and one for a robot nobody
knows), and declares a-0002's command queryable. The router lets its own
state through and nothing else: the IaaS keeps a-0002's real state, never
hears of a-0003, and a command for a-0002 reaches a-0002 alone.

Each refusal leaves a line in the IaaS's log and a count in its metrics
(``robocloud_router_refusals``): the IaaS reads its router's access control
trace (robocloud.federation.security.router_refusals).
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh
from processes import Cloud, wait_until
from secure_clouds import KICKER, listed, repliers, robot_state, secure_cloud, session_as

from robocloud.federation.security.policy import robot_name
from robocloud.fleet import keys
from robocloud.fleet.messages import Ack, State

pytestmark = pytest.mark.slow

CLOUD = "cloud-a"


def state(robot: str, seq: int, position: list[float], battery: float = 90.0) -> str:
    return robot_state(CLOUD, robot, seq, position, battery).model_dump_json()


class Answerer:
    """A queryable that answers an Ack and remembers the commands it was sent."""

    def __init__(self, session: zenoh.Session, robot: str) -> None:
        self.robot = robot
        self.heard: list[str] = []
        self._lock = threading.Lock()
        self.queryable = session.declare_queryable(keys.cmd_key(CLOUD, robot), self._on_query)

    def _on_query(self, query: zenoh.Query) -> None:
        with self._lock:
            self.heard.append(query.payload.to_string() if query.payload is not None else "")
        ack = Ack(ok=True, robot=self.robot, request_id="req-probe")
        query.reply(query.key_expr, ack.model_dump_json())


@pytest.fixture(scope="module")
def cloud_a(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Cloud, Path]]:
    tmp_path = tmp_path_factory.mktemp("identities")
    ids = tmp_path / "robot-ids.txt"
    ids.write_text("# robots of cloud-a with a certificate of their own\na-0001\na-0002\n")
    names = [f"{CLOUD}-robots", robot_name(CLOUD, "a-0001"), robot_name(CLOUD, "a-0002")]
    with secure_cloud(tmp_path, CLOUD, names, ["--robot-ids", str(ids)]) as made:
        yield made


def test_a_robot_certificate_speaks_for_its_robot_only(cloud_a: tuple[Cloud, Path]) -> None:
    cloud, certs = cloud_a
    real = session_as(cloud, certs, robot_name(CLOUD, "a-0002"))
    attacker = session_as(cloud, certs, robot_name(CLOUD, "a-0001"))
    tool = session_as(cloud, certs, CLOUD)  # the IaaS's own certificate: asks as the IaaS does
    try:
        # The real a-0002, with its own certificate: its state and its command key work.
        real_cmd = Answerer(real, "a-0002")
        real.put(keys.state_key(CLOUD, "a-0002"), state("a-0002", 1, [10.0, 10.0]))
        wait_until(
            lambda: listed(cloud).get("a-0002", {}).get("position") == [10.0, 10.0],
            20,
            "a-0002's own state to be accepted",
        )

        # The attacker: states for another robot, as one and in a batch, and one nobody knows.
        forged = state("a-0002", 2**40, [999.0, 999.0], battery=5.0)
        attacker.put(keys.state_key(CLOUD, "a-0002"), forged)
        attacker.put(keys.batch_key(CLOUD, "gw-1"), f"[{forged}]")
        attacker.put(keys.state_key(CLOUD, "a-0003"), state("a-0003", 1, [5.0, 5.0]))
        forged_cmd = Answerer(attacker, "a-0002")
        token = attacker.liveliness().declare_token(keys.sim_token(CLOUD, 1))
        # Then its own state and command key: once the IaaS has them, the router has judged
        # everything the attacker sent before (one link, in order).
        attacker.put(keys.state_key(CLOUD, "a-0001"), state("a-0001", 1, [1.0, 2.0]))
        own_cmd = Answerer(attacker, "a-0001")
        wait_until(
            lambda: listed(cloud).get("a-0001", {}).get("position") == [1.0, 2.0],
            20,
            "a-0001's own state to be accepted",
        )

        def ask(robot: str) -> list[str]:
            return repliers(tool, keys.cmd_key(CLOUD, robot), '{"type": "probe"}')

        wait_until(lambda: ask("a-0001"), 10, "a-0001 to answer its own commands")
        assert own_cmd.heard
        assert ask("a-0002") == [str(real.zid())]
        assert real_cmd.heard and forged_cmd.heard == []

        robots = listed(cloud)
        assert set(robots) == {"a-0001", "a-0002"}
        assert robots["a-0002"]["position"] == [10.0, 10.0]
        assert robots["a-0002"]["battery"] == 90.0
        assert robots["a-0002"]["status"] == "idle"
        assert robots["a-0002"].get("refused") is None
        # No simulator's token either: a robot's certificate declares none.
        assert list(tool.liveliness().get(keys.all_sim_tokens(CLOUD), timeout=1.0)) == []
        token.undeclare()  # type: ignore[no-untyped-call]
    finally:
        for session in (real, attacker, tool):
            session.close()  # type: ignore[no-untyped-call]
    attacker_name = robot_name(CLOUD, "a-0001")
    refused = {
        (attacker_name, "put"): 3.0,  # a-0002's state, the batch, a-0003's state
        (attacker_name, "declare_queryable"): 1.0,  # a-0002's command key
        (attacker_name, "liveliness_token"): 1.0,  # a simulator's token
    }
    wait_until(lambda: cloud.router_refusals() == refused, 10, "the refusals to be counted")
    log = (cloud.workdir / f"{CLOUD}-iaas.log").read_text()
    assert "999" not in log  # the forged state was never read
    said = [line for line in log.splitlines() if "router refused" in line]
    for key in (
        keys.state_key(CLOUD, "a-0002"),
        keys.batch_key(CLOUD, "gw-1"),
        keys.state_key(CLOUD, "a-0003"),
        keys.cmd_key(CLOUD, "a-0002"),
        keys.sim_token(CLOUD, 1),
    ):
        assert any(repr(key) in line and attacker_name in line for line in said), key
    assert all("a-0003" not in line for line in log.splitlines() if line not in said)


def test_a_forged_state_hides_a_robot_two_seconds_and_is_told(
    cloud_a: tuple[Cloud, Path],
) -> None:
    """The issue's fourth attack, with the fleet's certificate (which speaks for every robot
    of the cloud): a-0002's state re-published with ``seq`` 2**62, first with ``sent_at``
    1e15 (refused), then 250 s ahead (taken, and overtaken by a-0002's own state once
    ARRIVAL_SLACK has passed). Each leaves a log line and a count of
    ``robocloud_states_refused``."""
    cloud, certs = cloud_a
    real = session_as(cloud, certs, robot_name(CLOUD, "a-0002"))
    fleet = session_as(cloud, certs, f"{CLOUD}-robots")
    key = keys.state_key(CLOUD, "a-0002")

    def refused() -> dict[str, float]:
        with cloud.client() as client:
            text = client.get("/metrics").text
        return {
            line.split('"')[1]: float(line.rsplit(" ", 1)[1])
            for line in text.splitlines()
            if line.startswith("robocloud_states_refused_total{")
        }

    try:
        real.put(key, state("a-0002", 100, [10.0, 10.0]))
        wait_until(
            lambda: listed(cloud).get("a-0002", {}).get("position") == [10.0, 10.0],
            20,
            "a-0002's own state",
        )
        far = State.model_validate_json(state("a-0002", 2**62, [999.0, 999.0], battery=5.0))
        fleet.put(key, far.model_copy(update={"sent_at": 1e15}).model_dump_json())
        wait_until(lambda: refused().get("sent_at") == 1.0, 10, "the far state to be refused")
        ahead = far.model_copy(update={"sent_at": time.time() + 250.0})
        fleet.put(key, ahead.model_dump_json())
        wait_until(
            lambda: listed(cloud)["a-0002"]["position"] == [999.0, 999.0],
            10,
            "the forged state within the bound to be taken",
        )
        seq = iter(range(101, 10_000))

        def back() -> bool:
            real.put(key, state("a-0002", next(seq), [10.0, 10.0]))  # the robot goes on
            return bool(listed(cloud)["a-0002"]["position"] == [10.0, 10.0])

        # Within 20 s, not the 250 s the forged sent_at claimed: ARRIVAL_SLACK (2 s) after
        # it arrived, the robot's next state takes its place.
        wait_until(back, 20, "a-0002's own state to overtake the forged one")
        wait_until(lambda: refused().get("overtaken") == 1.0, 10, "the overtaking counted")
    finally:
        for session in (real, fleet):
            session.close()  # type: ignore[no-untyped-call]
    log = (cloud.workdir / f"{CLOUD}-iaas.log").read_text()
    assert "refused a state on robocloud/cloud-a/robots/a-0002/state (field sent_at)" in log
    assert f"robot a-0002's state of seq {2**62} claimed to be sent at" in log


def test_a_name_with_a_newline_forges_no_log_line(cloud_a: tuple[Cloud, Path]) -> None:
    """The issue's seventh attack with the fleet's certificate: a capability name holding a
    newline and a whole made-up log line, and a key holding one (refused by the router).
    Refused with a sentence, counted; the IaaS's log holds no line of the attacker's."""
    cloud, certs = cloud_a
    fleet = session_as(cloud, certs, f"{CLOUD}-robots")
    forged = "\n2026-12-02 04:30:00,000 cloud-a WARNING robocloud.iaas.home: cloud-b is back"
    raw = State.model_validate_json(state("a-0002", 10**6, [10.0, 10.0])).model_dump(mode="json")
    raw["capabilities"] = {f"kicker{forged}": KICKER["kicker"]}
    errors: list[str] = []
    told = fleet.declare_subscriber(
        keys.error_key(CLOUD, "a-0002"), lambda sample: errors.append(sample.payload.to_string())
    )
    try:
        fleet.put(keys.state_key(CLOUD, "a-0002"), json.dumps(raw))
        fleet.put(f"robocloud/{CLOUD}/x{forged}", "{}")  # not a key the fleet may put on
        wait_until(lambda: errors, 10, "a-0002 to be told why its state was refused")
    finally:
        told.undeclare()  # type: ignore[no-untyped-call]
        fleet.close()  # type: ignore[no-untyped-call]
    assert "capabilities" in json.loads(errors[0])["field"]
    wait_until(
        lambda: cloud.router_refusals().get((f"{CLOUD}-robots", "put"), 0) >= 1,
        10,
        "the router's refusal of the key to be counted",
    )
    lines = (cloud.workdir / f"{CLOUD}-iaas.log").read_text().splitlines()
    assert not [line for line in lines if line.startswith("2026-12-02 04:30:00,000")]
    escaped = [line for line in lines if "\\n2026-12-02 04:30:00,000" in line]
    assert len(escaped) >= 2, escaped  # the state's refusal and the router's, on one line each
