"""ZenohRobotLink against hand-written robots on a real loopback Zenoh network."""

import json
import threading
import time
from collections.abc import Callable, Iterator

import pytest
import zenoh
from fleet_testing import until_subscribed

from loopback_ports import free_endpoint
from robocloud.errors import InvalidInput
from robocloud.fleet import (
    Ack,
    Assign,
    State,
    ZenohRobotLink,
    keys,
    open_client,
    open_router,
    wait_for_liveliness,
)
from waiting import wait_until

GO = Assign(request_id="r-1", location=[10.0, 0.0], capabilities=["grabber"])
NOW = time.time()


@pytest.fixture(autouse=True)
def _states_of_now() -> None:
    """Each test's states are sent now: within the IaaS's clock bound (300 s), however
    long after the module's import the test runs (a full suite takes minutes)."""
    global NOW
    NOW = time.time()


def state(robot_id: str = "a-0001", seq: int = 1, **changes: object) -> bytes:
    fields: dict[str, object] = {
        "id": robot_id,
        "cloud": "cloud-a",
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
    return json.dumps(fields).encode()


@pytest.fixture(scope="module")
def network() -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    endpoint = free_endpoint()
    router = open_router([endpoint])
    client = open_client([endpoint])
    yield router, client
    client.close()  # type: ignore[no-untyped-call]
    router.close()  # type: ignore[no-untyped-call]


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_the_link_keeps_the_latest_valid_state_of_each_robot(
    network: tuple[zenoh.Session, zenoh.Session],
) -> None:
    router, client = network
    clock = Clock()
    with ZenohRobotLink(router, "cloud-a", offline_after=5.0, clock=clock) as link:
        heard: list[State] = []
        stop = link.on_state(heard.append)
        until_subscribed(client, keys.state_key("cloud-a", "a-0001"))
        put = client.put
        put(keys.state_key("cloud-a", "a-0001"), state(seq=2))
        put(keys.state_key("cloud-a", "a-0001"), state(seq=1, battery=10.0))  # older: ignored
        put(keys.state_key("cloud-a", "a-0002"), state("a-0003"))  # wrong key: ignored
        put(keys.state_key("cloud-a", "a-0004"), b"{not json")
        put(keys.state_key("cloud-b", "a-0005"), state("a-0005"))  # another cloud
        put(keys.state_key("cloud-a", "a-0006"), state("a-0006", cloud="cloud-b"))
        put(keys.state_key("cloud-a", "a-0007"), state("a-0007", seq=5))
        assert wait_until(lambda: "a-0007" in link.states())
        assert sorted(link.states()) == ["a-0001", "a-0007"]
        assert link.states()["a-0001"].battery == 90.0
        assert [s.id for s in heard] == ["a-0001", "a-0007"]
        stop()

        clock.now = 4.0
        put(keys.state_key("cloud-a", "a-0007"), state("a-0007", seq=6, status="busy"))
        assert wait_until(lambda: link.states()["a-0007"].seq == 6)
        clock.now = 6.0
        assert {r.id: r.status for r in link.robots()} == {"a-0001": "offline", "a-0007": "busy"}
        assert link.ages() == {"a-0001": 6.0, "a-0007": 2.0}
        assert len(heard) == 2  # the listener was removed


def test_commands_reach_the_robot_and_come_back_as_acks(
    network: tuple[zenoh.Session, zenoh.Session],
) -> None:
    router, client = network
    received: list[dict[str, object]] = []
    held: list[zenoh.Query] = []

    def robot(query: zenoh.Query) -> None:
        robot_id = keys.robot_of(str(query.key_expr))
        assert query.payload is not None
        received.append(json.loads(query.payload.to_bytes()))
        key = keys.cmd_key("cloud-b", str(robot_id))
        answers: dict[str, Callable[[], None]] = {
            "b-ok": lambda: query.reply(
                key, Ack(ok=True, robot="b-ok", request_id="r-1").model_dump_json()
            ),
            "b-junk": lambda: query.reply(key, b"[1, 2]"),
            "b-err": lambda: query.reply_err(b"overheated"),
            "b-mute": lambda: None,
        }
        if robot_id == "b-slow":
            held.append(query)  # never answered, never finalised: the get times out
            return
        with query:
            answers[str(robot_id)]()

    queryable = client.declare_queryable(keys.all_cmds("cloud-b"), robot)
    token = client.liveliness().declare_token(keys.sim_token("cloud-b", 1))
    try:
        assert wait_for_liveliness(router, keys.all_sim_tokens("cloud-b"), 2.0)
        link = ZenohRobotLink(router, "cloud-b", command_timeout=0.3)
        assert link.assign("b-ok", GO) == Ack(ok=True, robot="b-ok", request_id="r-1")
        assert received[-1] == json.loads(GO.model_dump_json())
        assert link.cancel("b-ok", "r-1").ok
        assert received[-1] == {"type": "cancel", "request_id": "r-1"}
        junk = link.assign("b-junk", GO)
        assert junk.error == "robot b-junk answered something that is not an Ack."
        assert link.assign("b-err", GO).error == "robot b-err answered an error: overheated"
        assert link.assign("b-mute", GO).unanswered
        started = time.monotonic()
        slow = link.assign("b-slow", GO)
        assert not slow.ok and slow.unanswered
        assert 0.25 < time.monotonic() - started < 2.0
        link.close()
    finally:
        for query in held:
            query.drop()  # type: ignore[no-untyped-call]
        token.undeclare()  # type: ignore[no-untyped-call]
        queryable.undeclare()  # type: ignore[no-untyped-call]


def test_a_command_to_nobody_is_not_answered_at_once(
    network: tuple[zenoh.Session, zenoh.Session],
) -> None:
    router, _ = network
    link = ZenohRobotLink(router, "cloud-c", command_timeout=5.0)
    started = time.monotonic()
    assert link.assign("c-0001", GO).unanswered
    assert time.monotonic() - started < 1.0  # no route: Zenoh ends the query at once
    link.close()


def test_liveliness_wait_and_session_errors(
    network: tuple[zenoh.Session, zenoh.Session],
) -> None:
    router, client = network
    assert not wait_for_liveliness(router, keys.all_sim_tokens("cloud-z"), 0.2)
    later = threading.Timer(
        0.2, lambda: tokens.append(client.liveliness().declare_token("robocloud/cloud-z/sim/7"))
    )
    tokens: list[zenoh.LivelinessToken] = []
    later.start()
    assert wait_for_liveliness(router, keys.all_sim_tokens("cloud-z"), 3.0)
    later.join()
    tokens[0].undeclare()  # type: ignore[no-untyped-call]

    closed = free_endpoint()
    with pytest.raises(InvalidInput, match=r"cannot open a Zenoh session on tcp/127\.0\.0\.1:"):
        open_client([closed])
    started = time.monotonic()
    with pytest.raises(InvalidInput):
        open_client([closed], timeout=0.5)
    assert time.monotonic() - started >= 0.5
    with pytest.raises(InvalidInput, match="cannot open"):
        open_client(["nonsense"])
    with pytest.raises(InvalidInput):
        open_router([])


def test_a_refused_state_is_answered_on_the_robots_error_key_and_logged(
    network: tuple[zenoh.Session, zenoh.Session], caplog: pytest.LogCaptureFixture
) -> None:
    router, client = network
    answers: list[dict[str, object]] = []
    lock = threading.Lock()

    def heard(sample: zenoh.Sample) -> None:
        with lock:
            answers.append({"key": str(sample.key_expr), **json.loads(sample.payload.to_bytes())})

    listening = client.declare_subscriber("robocloud/cloud-a/robots/*/error", heard)
    with ZenohRobotLink(router, "cloud-a") as link:
        until_subscribed(client, keys.state_key("cloud-a", "a-0100"))
        until_subscribed(router, "robocloud/cloud-a/robots/a-0100/error")
        key = keys.state_key("cloud-a", "a-0100")
        missing = json.loads(state("a-0100"))
        del missing["kind"]
        client.put(key, json.dumps(missing))
        assert wait_until(lambda: len(answers) == 1)
        answered = time.monotonic()
        # Repeated within the second: logged once, answered once.
        for battery in (150.0, 0.5):
            client.put(key, state("a-0100", seq=2, battery=battery))
        repeated = time.monotonic() - answered
        client.put(keys.state_key("cloud-a", "a-0101"), state("a-0102"))
        # Fragmented on the wire: BLOCK, as Zenoh's default (DROP) may drop it when the
        # puts just before fill the queue.
        client.put(
            keys.state_key("cloud-a", "a-0103"),
            b"x" * 70_000,
            congestion_control=zenoh.CongestionControl.BLOCK,
        )
        assert wait_until(lambda: len(answers) >= 3), [a["key"] for a in answers]
        # The valid one (battery 0.5 %) was taken.
        assert wait_until(lambda: "a-0100" in link.states())
    listening.undeclare()  # type: ignore[no-untyped-call]
    if repeated < 0.5:  # a loaded machine may take longer than the second between them
        assert len(answers) == 3, answers
    by_key: dict[object, dict[str, object]] = {}
    for answer in answers:
        by_key.setdefault(answer["key"], answer)
    first = by_key["robocloud/cloud-a/robots/a-0100/error"]
    assert first["field"] == "kind"
    assert first["error"] == "kind is missing."
    assert first["robot"] == "a-0100"
    assert first["protocol"] == "1.2"
    mismatch = by_key["robocloud/cloud-a/robots/a-0101/error"]
    assert mismatch["field"] == "id"
    assert "names robot a-0102 but came on the key of a-0101" in str(mismatch["error"])
    assert "70000 bytes" in str(by_key["robocloud/cloud-a/robots/a-0103/error"]["error"])
    logged = [r.getMessage() for r in caplog.records if "refused a state" in r.getMessage()]
    assert any("a-0100/state (field kind): kind is missing." in line for line in logged)
    assert any(
        "(field battery): battery: input should be less than or equal to 100" in line
        for line in logged
    ), logged


def test_a_forged_state_cannot_hide_a_robot(
    network: tuple[zenoh.Session, zenoh.Session],
) -> None:
    """The attacker re-publishes a robot's state with a huge seq and a far sent_at."""
    router, client = network
    clock = Clock()
    errors: list[dict[str, object]] = []
    told = client.declare_subscriber(
        keys.error_key("cloud-a", "a-0100"),
        lambda s: errors.append(json.loads(s.payload.to_bytes())),
    )
    key = keys.state_key("cloud-a", "a-0100")
    with ZenohRobotLink(
        router, "cloud-a", offline_after=5.0, clock=clock, wall=lambda: NOW + clock.now
    ) as link:
        until_subscribed(client, key)
        until_subscribed(router, keys.error_key("cloud-a", "a-0100"))
        client.put(key, state("a-0100", seq=1))
        assert wait_until(lambda: "a-0100" in link.states())
        # Far in the future: refused, with a sentence on the robot's error key.
        client.put(key, state("a-0100", seq=2**62, sent_at=1e15, battery=1.0))
        assert wait_until(lambda: errors)
        assert errors[0]["field"] == "sent_at"
        assert "ahead of this IaaS's clock; at most 300 s apart" in str(errors[0]["error"])
        client.put(key, state("a-0100", seq=2, battery=80.0))
        assert wait_until(lambda: link.states()["a-0100"].battery == 80.0)
        # Within the bound but ahead of every real state: it counts as sent when it
        # arrived plus ARRIVAL_SLACK (2 s), so the robot's next states overtake it.
        kept: list[float] = []
        link.on_state(lambda s: kept.append(s.battery) if s.id == "a-0100" else None)
        client.put(key, state("a-0100", seq=2**62, sent_at=NOW + 250, battery=2.0))
        assert wait_until(lambda: link.states()["a-0100"].battery == 2.0)
        client.put(key, state("a-0100", seq=3, sent_at=NOW + 1, battery=70.0))  # dropped
        clock.now = 3.0  # 3 s on, for the IaaS and the robot
        client.put(key, state("a-0100", seq=4, sent_at=NOW + 3, battery=60.0))
        assert wait_until(lambda: link.states()["a-0100"].battery == 60.0)
        assert kept == [2.0, 60.0], "the robot's state sent within the slack was dropped"
        assert link.state_refusals() == {"sent_at": 1, "overtaken": 1}
        assert {r.id: r.status for r in link.robots()}["a-0100"] == "idle"
    told.undeclare()  # type: ignore[no-untyped-call]


def test_a_robot_whose_states_are_refused_is_told_why_in_the_link(
    network: tuple[zenoh.Session, zenoh.Session],
) -> None:
    """Issue 25: refused states left a robot silently offline; the link now keeps the reason."""
    router, client = network
    key = keys.state_key("cloud-a", "a-0200")
    batch = keys.batch_key("cloud-a", "gw-1")
    with ZenohRobotLink(router, "cloud-a") as link:
        until_subscribed(client, key)
        until_subscribed(client, batch)
        client.put(key, state("a-0200", seq=1, sent_at=NOW + 900))  # never accepted
        assert wait_until(lambda: "a-0200" in link.refused())
        assert "900 s ahead of this IaaS's clock" in link.refused()["a-0200"]
        assert "a-0200" not in link.states()
        # A gateway's batch: the robot its state names is told, the others go on.
        good, late = json.loads(state("a-0201")), json.loads(state("a-0202", sent_at=NOW - 900))
        client.put(batch, json.dumps([good, late]).encode())
        assert wait_until(lambda: "a-0202" in link.refused())
        assert "behind this IaaS's clock" in link.refused()["a-0202"]
        assert "a-0201" in link.states() and "a-0201" not in link.refused()
        # One state accepted, and the reason is gone.
        client.put(key, state("a-0200", seq=2))
        assert wait_until(lambda: "a-0200" not in link.refused())
        assert "a-0200" in link.states()
