"""The home of a robot: it lends it to other clouds' requests and enforces the leases.

Clouds in memory (``federation_testing``): the sender of a command is the
calling cloud, as the router guarantees with mutual TLS (that guarantee has
its own tests on real Zenoh routers in ``test_overlay_security``).
"""

from __future__ import annotations

import logging

import pytest
from federation_testing import Cloud, FakeTime, clouds

from robocloud.federation.memory import MemoryNetwork
from robocloud.federation.messages import (
    Dispatch,
    LoanQuery,
    Release,
    Reservation,
    StatusQuery,
)
from robocloud.federation.overlay import Unreachable
from robocloud.fleet.messages import Assign

NAMES = ("cloud-a", "cloud-b", "cloud-c")


def go(request_id: str) -> Assign:
    return Assign(request_id=request_id, location=[0.0, 0.0], capabilities=["grabber"])


@pytest.fixture
def time() -> FakeTime:
    return FakeTime()


@pytest.fixture
def fed(time: FakeTime) -> tuple[MemoryNetwork, dict[str, Cloud]]:
    # cloud-b lends to cloud-a and cloud-c, as in the README's example.
    return clouds(NAMES, trust={"cloud-b": ["cloud-a", "cloud-c"]}, time=time)


def lend(a: Cloud, request_id: str, robots: list[str], dispatch: bool = True) -> None:
    """What the origin's service does: reserve, dispatch, confirm, then follow the robots."""
    assert (
        a.overlay.reserve("cloud-b", Reservation(request_id=request_id, robots=robots)).taken == []
    )
    if dispatch:
        for robot in robots:
            assert a.overlay.dispatch("cloud-b", Dispatch(robot=robot, command=go(request_id))).ok
        assert (
            a.overlay.confirm("cloud-b", Reservation(request_id=request_id, robots=robots)).taken
            == []
        )
        a.origin.coalitions[request_id] = robots


def test_the_home_sets_the_lease_whatever_the_origin_asks(
    fed: tuple[MemoryNetwork, dict[str, Cloud]], time: FakeTime
) -> None:
    _, c = fed
    a, b = c["cloud-a"], c["cloud-b"]
    for asked in (None, 5.0, 3600.0):
        rid = f"req-{asked}"
        a.overlay.reserve(
            "cloud-b", Reservation(request_id=rid, robots=["b-0"], lease_seconds=asked)
        )
        loan = b.store.loan_of("b-0")
        assert loan is not None and loan.origin == "cloud-a" and loan.expires_at is not None
        granted = (loan.expires_at - time.utc()).total_seconds()
        assert granted == pytest.approx(30.0 if asked != 5.0 else 5.0, abs=0.001)
        assert b.home.lent_for("b-0") == rid
        a.overlay.release("cloud-b", Release(request_id=rid))
        assert b.home.lent_for("b-0") is None
    # An absurd lease is refused by the message's bounds before any work.
    with pytest.raises(Unreachable, match="less than or equal to 86400"):
        a.overlay.reserve(
            "cloud-b",
            Reservation.model_construct(request_id="r", robots=["b-0"], lease_seconds=1e9),
        )


def test_a_lease_lapses_unless_dispatched_and_a_confirm_needs_it_live(
    fed: tuple[MemoryNetwork, dict[str, Cloud]], time: FakeTime
) -> None:
    _, c = fed
    a, b = c["cloud-a"], c["cloud-b"]
    rid = a.store.create_request("app", {})[0].id
    a.origin.coalitions[rid] = ["b-0"]
    # A confirm without a reserve never takes a robot.
    reply = a.overlay.confirm("cloud-b", Reservation(request_id=rid, robots=["b-0"]))
    assert reply.taken == ["b-0"] and "no live lease" in (reply.error or "")
    assert b.store.reservations() == {}
    a.overlay.reserve("cloud-b", Reservation(request_id=rid, robots=["b-0", "b-1", "b-2"]))
    # A lease stays a lease until the home forwarded its robot's dispatch.
    reply = a.overlay.confirm("cloud-b", Reservation(request_id=rid, robots=["b-0", "b-2"]))
    assert reply.taken == ["b-0", "b-2"] and "forwarded no dispatch" in (reply.error or "")
    for robot in ("b-0", "b-2"):
        assert a.overlay.dispatch("cloud-b", Dispatch(robot=robot, command=go(rid))).ok
    assert (
        a.overlay.confirm("cloud-b", Reservation(request_id=rid, robots=["b-0", "b-2"])).taken == []
    )
    firm = b.store.loan_of("b-0")
    assert firm is not None and firm.state == "firm"
    time.advance(31)
    # b-1's lease lapsed (never dispatched); b-0 and b-2 are firm.
    assert b.home.lent_for("b-1") is None and b.home.lent_for("b-0") == rid
    reply = a.overlay.confirm("cloud-b", Reservation(request_id=rid, robots=["b-0", "b-1"]))
    assert reply.taken == ["b-1"] and "no live lease" in (reply.error or "")
    assert a.overlay.confirm("cloud-b", Reservation(request_id=rid, robots=["b-0"])).taken == []
    b.reconciler.reconcile()  # cloud-a still uses b-0, not b-2
    assert [loan.robot for loan in b.store.loans()] == ["b-0"]


def test_a_refused_dispatch_keeps_nothing(
    fed: tuple[MemoryNetwork, dict[str, Cloud]], time: FakeTime
) -> None:
    _, c = fed
    a, b = c["cloud-a"], c["cloud-b"]
    a.overlay.reserve("cloud-b", Reservation(request_id="req-1", robots=["b-0"]))
    lacking = Assign(request_id="req-1", location=[0.0, 0.0], capabilities=["light"])
    ack = a.overlay.dispatch("cloud-b", Dispatch(robot="b-0", command=lacking))
    assert not ack.ok and "light" in (ack.error or "")
    time.advance(31)  # the lease lapses as if never dispatched
    assert b.home.lent_for("b-0") is None
    assert a.overlay.confirm("cloud-b", Reservation(request_id="req-1", robots=["b-0"])).taken


def test_dispatch_only_for_a_robot_lent_to_the_senders_request(
    fed: tuple[MemoryNetwork, dict[str, Cloud]], caplog: pytest.LogCaptureFixture
) -> None:
    _, c = fed
    a, b, cc = c["cloud-a"], c["cloud-b"], c["cloud-c"]
    ack = a.overlay.dispatch("cloud-b", Dispatch(robot="b-0", command=go("req-1")))
    assert not ack.ok and "not lent" in (ack.error or "")
    lend(a, "req-1", ["b-0"], dispatch=False)
    with caplog.at_level(logging.INFO, logger="robocloud.federation.home"):
        ack = cc.overlay.dispatch("cloud-b", Dispatch(robot="b-0", command=go("req-1")))
    assert not ack.ok
    assert (
        "refused a dispatch from cloud-c for request req-1: b-0 is lent to cloud-a" in caplog.text
    )
    assert b.link.commands == []  # the robot never heard of it
    assert a.overlay.dispatch("cloud-b", Dispatch(robot="b-0", command=go("req-1"))).ok
    assert [robot for robot, _ in b.link.commands] == ["b-0"]


def test_cloud_c_cannot_touch_cloud_as_loans(
    fed: tuple[MemoryNetwork, dict[str, Cloud]], caplog: pytest.LogCaptureFixture
) -> None:
    _, c = fed
    a, b, cc = c["cloud-a"], c["cloud-b"], c["cloud-c"]
    lend(a, "req-1", ["b-0", "b-1"])
    before = b.store.loans()
    with caplog.at_level(logging.WARNING, logger="robocloud.federation.home"):
        released = cc.overlay.release("cloud-b", Release(request_id="req-1"))
        canceled = cc.overlay.cancel("cloud-b", Release(request_id="req-1", robots=["b-0"]))
        confirmed = cc.overlay.confirm("cloud-b", Reservation(request_id="req-1", robots=["b-1"]))
        taken = cc.overlay.reserve("cloud-b", Reservation(request_id="req-1", robots=["b-1"]))
    assert not released.ok and "cloud-c holds no loan" in (released.error or "")
    assert not canceled.ok
    assert confirmed.taken == ["b-1"] and confirmed.error
    assert taken.taken == ["b-1"]  # another holder has it
    refusals = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(refusals) == 3, refusals
    assert all("from cloud-c" in line and "lent to cloud-a" in line for line in refusals)
    assert b.store.loans() == before
    assert [cmd.type for _, cmd in b.link.commands] == ["assign", "assign"]  # no cancel
    # cloud-a's own release works.
    assert a.overlay.release("cloud-b", Release(request_id="req-1")).ok
    assert b.store.loans() == []


def test_an_untrusted_cloud_is_refused(fed: tuple[MemoryNetwork, dict[str, Cloud]]) -> None:
    _, c = fed
    a = c["cloud-a"]
    # cloud-a trusts every cloud (no --trust): cloud-b may borrow; cloud-b trusts a and c only.
    reply = c["cloud-b"].overlay.reserve("cloud-a", Reservation(request_id="r", robots=["a-0"]))
    assert reply.taken == []
    network, more = clouds(("cloud-a", "cloud-b"), trust={"cloud-b": ["cloud-c"]})
    reply = more["cloud-a"].overlay.reserve("cloud-b", Reservation(request_id="r", robots=["b-0"]))
    assert reply.taken == ["b-0"] and "does not trust cloud-a" in (reply.error or "")
    assert more["cloud-b"].store.reservations() == {}
    assert a.overlay.gather_idle  # (the view's gather is tested in test_view)
    assert network.calls[-1] == ("cloud-a", "cloud-b", "reserve")


def test_unknown_robots_and_oversized_messages_are_refused(
    fed: tuple[MemoryNetwork, dict[str, Cloud]],
) -> None:
    _, c = fed
    a = c["cloud-a"]
    reply = a.overlay.reserve("cloud-b", Reservation(request_id="r", robots=["b-0", "x-9"]))
    assert reply.error == "cloud-b has no robot x-9."
    too_many = Reservation.model_construct(request_id="r", robots=[f"b-{i}" for i in range(1001)])
    with pytest.raises(Unreachable, match="invalid message"):
        a.overlay.reserve("cloud-b", too_many)
    huge = Reservation.model_construct(request_id="r" * 2_000_000, robots=["b-0"])
    with pytest.raises(Unreachable, match="at most 1048576"):
        a.overlay.reserve("cloud-b", huge)
    assert c["cloud-b"].store.reservations() == {}


def test_a_robot_that_finishes_comes_back_home(fed: tuple[MemoryNetwork, dict[str, Cloud]]) -> None:
    _, c = fed
    a, b = c["cloud-a"], c["cloud-b"]
    lend(a, "req-1", ["b-0"])
    assert b.home.lent_for("b-0") == "req-1"
    b.link.step(10_000)  # drives there, works, done
    assert b.home.lent_for("b-0") is None
    assert b.store.loans() == []
    lend(a, "req-2", ["b-1"])
    b.link.fail("b-1")
    assert b.home.lent_for("b-1") is None


def test_lent_for_never_asks_the_store(fed: tuple[MemoryNetwork, dict[str, Cloud]]) -> None:
    _, c = fed
    a, b = c["cloud-a"], c["cloud-b"]
    lend(a, "req-1", ["b-0"])
    calls: list[str] = []
    store = b.home.store

    class Counting:
        def __getattr__(self, name: str) -> object:
            calls.append(name)
            return getattr(store, name)

    b.home.store = Counting()  # type: ignore[assignment]
    for _ in range(1000):
        assert b.home.lent_for("b-0") == "req-1"
        assert b.home.lent_for("b-2") is None
    assert calls == []


def test_a_stale_copy_of_a_loan_never_brings_it_back(
    fed: tuple[MemoryNetwork, dict[str, Cloud]],
) -> None:
    _, c = fed
    a, b = c["cloud-a"], c["cloud-b"]
    lend(a, "req-1", ["b-0"])
    stale = b.store.loans()  # read by one thread...
    assert a.overlay.release("cloud-b", Release(request_id="req-1")).ok  # ...ended by another
    for loan in stale:
        b.home._remember(loan)  # the first thread caches what it read, late
    assert b.home.lent_for("b-0") is None
    b.link.cancel("b-0", "req-1")  # cloud-a stops it: idle, it may be lent again
    lend(a, "req-2", ["b-0"], dispatch=False)  # the robot's next loan is newer: it counts
    assert b.home.lent_for("b-0") == "req-2"


def test_the_origin_decides_which_loans_it_still_uses(
    fed: tuple[MemoryNetwork, dict[str, Cloud]], time: FakeTime
) -> None:
    _, c = fed
    a, b = c["cloud-a"], c["cloud-b"]
    record, _ = a.store.create_request("app", {})
    lend(a, record.id, ["b-0", "b-1"])
    lend(a, "req-gone", ["b-2"])
    a.origin.coalitions[record.id] = ["b-0"]  # b-1 failed over to another robot
    b.reconciler.reconcile()
    assert len(b.store.loans()) == 3  # too young to judge: the origin may not know them yet
    time.advance(11)
    # req-gone is not a request of cloud-a's store: unknown, so over.
    b.reconciler.reconcile()
    assert [loan.robot for loan in b.store.loans()] == ["b-0"]
    cancels = [(r, cmd.request_id) for r, cmd in b.link.commands if cmd.type == "cancel"]
    assert cancels == [("b-2", "req-gone")]
    a.store.transition(record.id, "canceled")
    b.reconciler.reconcile()
    assert b.store.loans() == []


def test_an_origin_away_past_the_deadline_loses_its_loans_and_learns_it_back(
    fed: tuple[MemoryNetwork, dict[str, Cloud]],
    time: FakeTime,
    caplog: pytest.LogCaptureFixture,
) -> None:
    network, c = fed
    a, b = c["cloud-a"], c["cloud-b"]
    record, _ = a.store.create_request("app", {"x": 1})
    rid = record.id
    a.view.reserve(rid, [("b-0", "cloud-b"), ("b-1", "cloud-b")])
    for robot in ("b-0", "b-1"):
        assert a.view.assign(robot, "cloud-b", go(rid)).ok
    assert a.view.confirm(rid, [("b-0", "cloud-b"), ("b-1", "cloud-b")]) == []
    a.origin.coalitions[rid] = ["b-0", "b-1"]
    b.link.step(5)  # both on their way
    b.link.cancel("b-1", rid)  # b-1 stops (its work is over here): idle, still lent
    time.advance(11)
    network.cut("cloud-a")

    def wait(seconds: int) -> None:
        """Time passes; b-0 keeps reporting its travel, as robots do every second."""
        for _ in range(seconds):
            time.advance(1)
            b.link.step(0)

    with caplog.at_level(logging.INFO, logger="robocloud.federation.home"):
        b.reconciler.reconcile()  # cloud-a does not answer: the clock starts
        wait(59)
        b.reconciler.reconcile()
        assert len(b.store.loans()) == 2
        wait(2)
        b.reconciler.reconcile()
        # b-1 is idle: its loan ends; b-0 still travels for cloud-a: it stays.
        assert [loan.robot for loan in b.store.loans()] == ["b-0"]
        assert [loan.robot for loan in b.store.untold_loans("cloud-a")] == ["b-1"]
        b.link.step(10_000)  # b-0 finishes: its loan ends as any finished one
        assert b.store.loans() == []
        network.mend("cloud-a")
        b.reconciler.reconcile()
        a.reconciler.reconcile()  # cloud-a asks its lenders
        a.reconciler.reconcile()  # told once only
    assert a.origin.ended == [
        (rid, "b-1", "cloud-b", "cloud-a was unreachable for 60 s while robot b-1 was idle or done")
    ]
    assert b.store.untold_loans("cloud-a") == []
    lines = caplog.text
    assert "cloud-a does not answer; its 2 loans wait for it" in lines
    assert "ended the loan of b-1 to cloud-a's request" in lines
    assert "cloud-a is back; 1 of its loans ended while it was away (b-1)" in lines
    assert "cloud-a, back, took in that the loan of b-1" in lines
    assert "cloud-b ended the loan of b-1 to request" in lines


def test_a_home_notes_an_origin_back_that_asked_for_its_ended_loans_first(
    fed: tuple[MemoryNetwork, dict[str, Cloud]],
    time: FakeTime,
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The origin, back, may ask its lenders before the home probes it: the home
    still notes it back, with the loans it ended meanwhile."""
    network, c = fed
    a, b = c["cloud-a"], c["cloud-b"]
    record, _ = a.store.create_request("app", {"x": 1})
    rid = record.id
    a.view.reserve(rid, [("b-1", "cloud-b")])
    assert a.view.assign("b-1", "cloud-b", go(rid)).ok
    assert a.view.confirm(rid, [("b-1", "cloud-b")]) == []
    a.origin.coalitions[rid] = ["b-1"]
    b.link.step(5)
    b.link.cancel("b-1", rid)  # idle, still lent
    time.advance(11)
    network.cut("cloud-a")
    with caplog.at_level(logging.INFO, logger="robocloud.federation.reconcile"):
        b.reconciler.reconcile()  # cloud-a does not answer: the clock starts
        time.advance(61)
        b.link.step(0)
        b.reconciler.reconcile()
        assert b.store.loans() == []
        network.mend("cloud-a")
        a.reconciler.reconcile()  # cloud-a asks first, and is told
        assert b.store.untold_loans("cloud-a") == []
        b.reconciler.reconcile()
        b.reconciler.reconcile()  # noted once
    assert a.origin.ended == [
        (rid, "b-1", "cloud-b", "cloud-a was unreachable for 60 s while robot b-1 was idle or done")
    ]
    backs = [r.getMessage() for r in caplog.records if "cloud-a is back" in r.getMessage()]
    assert backs == [
        "cloud-a is back; 1 of its loans ended while it was away (b-1); it asked, and was told"
    ]


def test_a_cancel_stops_a_robot_still_working_after_its_loan_ended(
    fed: tuple[MemoryNetwork, dict[str, Cloud]], time: FakeTime
) -> None:
    network, c = fed
    a, b, cc = c["cloud-a"], c["cloud-b"], c["cloud-c"]
    lend(a, "req-1", ["b-0"])
    network.cut("cloud-a")
    b.link.silence("b-0")  # it works on, unheard
    time.advance(6)  # silent: offline for its home
    b.reconciler.reconcile()
    time.advance(61)
    b.reconciler.reconcile()
    assert b.home.lent_for("b-0") is None  # the loan ended; the cancel went unheard
    network.mend("cloud-a")
    b.link.recover("b-0")
    task = b.link.states()["b-0"].task
    assert task is not None and task.request_id == "req-1"
    # No loan holds it, and it works for req-1: cloud-a's cancel stops it.
    assert a.overlay.cancel("cloud-b", Release(request_id="req-1", robots=["b-0"])).ok
    assert b.link.states()["b-0"].task is None
    # A robot lent to another origin is never stopped that way.
    b.link.put(b.link.states()["b-1"])  # it reports again (idle robots lend only when heard)
    lend(cc, "req-9", ["b-1"])
    assert a.overlay.cancel("cloud-b", Release(request_id="req-9", robots=["b-1"])).ok is False
    task = b.link.states()["b-1"].task
    assert task is not None and task.request_id == "req-9"


def test_status_answers_for_many_requests_at_once(
    fed: tuple[MemoryNetwork, dict[str, Cloud]],
) -> None:
    _, c = fed
    a = c["cloud-a"]
    done, _ = a.store.create_request("app", {})
    a.store.transition(done.id, "canceled")
    live, _ = a.store.create_request("app", {})
    a.origin.coalitions[live.id] = ["b-0"]
    reply = c["cloud-b"].overlay.status(
        "cloud-a", StatusQuery(home="cloud-b", request_ids=[done.id, live.id, "req-nope"])
    )
    assert [(s.known, s.final, s.robots) for s in reply.requests] == [
        (True, True, []),
        (True, False, ["b-0"]),
        (False, False, []),
    ]


def test_loans_query_answers_only_the_senders_loans(
    fed: tuple[MemoryNetwork, dict[str, Cloud]],
) -> None:
    _, c = fed
    a, b, cc = c["cloud-a"], c["cloud-b"], c["cloud-c"]
    lend(a, "req-1", ["b-0"])
    b.store.end_loans("cloud-a", "req-1", None, "gone", tell_origin=True)
    lend(cc, "req-9", ["b-1"])
    assert cc.overlay.loans("cloud-b", LoanQuery()).ended == []
    notice = a.overlay.loans("cloud-b", LoanQuery()).ended
    assert [(n.robot, n.request_id, n.why) for n in notice] == [("b-0", "req-1", "gone")]
    # cloud-c cannot mark cloud-a's notices as told.
    cc.overlay.loans("cloud-b", LoanQuery(told=[notice[0].loan]))
    assert len(a.overlay.loans("cloud-b", LoanQuery()).ended) == 1
    reply = a.overlay.loans("cloud-b", LoanQuery(told=[notice[0].loan]))
    assert reply.ended == [] and reply.held == 0
