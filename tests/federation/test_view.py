"""The federation view: one selection's robots from every cloud, reserved at each robot's home."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from federation_testing import FakeTime, clouds

from robocloud.domain import Task
from robocloud.federation.memory import MemoryNetwork
from robocloud.federation.view import GATHER_TTL, RESERVATIONS_TTL
from robocloud.fleet.messages import Assign

TASK = Task.model_validate(
    {
        "location": [0.0, 0.0],
        "actuating": {"grabber": 1},
        "max_robots": 3,
        "max_cost": 100.0,
        "max_time": 300.0,
        "min_battery": 50.0,
    }
)


def go(request_id: str) -> Assign:
    return Assign(request_id=request_id, location=[0.0, 0.0], capabilities=["grabber"])


def test_remote_robots_leave_out_a_cloud_that_does_not_answer() -> None:
    time = FakeTime()
    network, c = clouds(("cloud-a", "cloud-b", "cloud-c"), robots=2, time=time)
    view = c["cloud-a"].view
    seen = view.remote_robots(TASK, exclude={"b-1"})
    assert sorted(r.id for r in seen.robots) == ["b-0", "c-0", "c-1"]
    assert seen.notes == []
    time.advance(GATHER_TTL)  # each question below is asked again
    network.mute("cloud-c")
    seen = view.remote_robots(TASK, exclude=set())
    assert sorted(r.id for r in seen.robots) == ["b-0", "b-1"]
    assert seen.notes == ["cloud-c did not answer within 500 ms; its robots were left out"]
    network.cut("cloud-c")  # gone: no longer expected
    assert view.remote_robots(TASK, exclude=set()).notes == []
    network.mend("cloud-c")
    time.advance(GATHER_TTL)
    # A lent robot is no longer idle at its home.
    assert c["cloud-c"].view.reserve("req-c", [("b-0", "cloud-b")]) == []
    assert sorted(r.id for r in view.remote_robots(TASK, exclude=set()).robots) == [
        "b-1",
        "c-0",
        "c-1",
    ]


def test_reserve_is_all_or_nothing_across_clouds() -> None:
    _, c = clouds(("cloud-a", "cloud-b", "cloud-c"), robots=2)
    a, b, cc = c["cloud-a"], c["cloud-b"], c["cloud-c"]
    assert cc.view.reserve("req-c", [("b-1", "cloud-b")]) == []
    rid, _ = a.store.create_request("app", {})
    pairs = [("a-0", "cloud-a"), ("c-0", "cloud-c"), ("b-0", "cloud-b"), ("b-1", "cloud-b")]
    assert a.view.reserve(rid.id, pairs) == ["b-1"]
    # Every hold of the try is given back: at home and at cloud-c.
    assert a.store.reservations() == {}
    assert cc.store.loans() == []
    assert [loan.robot for loan in b.store.loans()] == ["b-1"]
    assert a.view.lenders() == ["cloud-b", "cloud-c"]
    assert a.view.reserve(rid.id, pairs[:3]) == []
    assert [r.id for r in a.view.local_robots() if r.status == "reserved"] == ["a-0"]


def test_dispatch_confirm_follow_and_cancel_a_remote_robot() -> None:
    _, c = clouds(("cloud-a", "cloud-b"), robots=2)
    a, b = c["cloud-a"], c["cloud-b"]
    rid = "req-a1"
    # Confirming without a lease reports the robot lost.
    assert a.view.confirm(rid, [("b-0", "cloud-b")]) == ["b-0"]
    assert a.view.reserve(rid, [("b-0", "cloud-b")]) == []
    ack = a.view.assign("b-0", "cloud-b", go(rid))
    assert ack.ok
    assert a.view.confirm(rid, [("b-0", "cloud-b")]) == []
    assert ("cloud-b", "b-0") in a.overlay.watched()
    b.link.step(2)
    state = a.overlay.states()["b-0"]
    assert state.task is not None and state.task.request_id == rid
    assert "b-0" in a.view.ages()
    heard: list[str] = []
    stop = a.view.on_state(lambda s: heard.append(s.id))
    b.link.step(1)
    stop()
    assert heard == ["b-0"]
    a.view.cancel("b-0", "cloud-b", rid)
    assert b.store.loans() == []
    assert b.link.states()["b-0"].task is None
    assert ("cloud-b", "b-0") not in a.overlay.watched()


def test_release_gives_robots_back_to_every_home() -> None:
    _, c = clouds(("cloud-a", "cloud-b"), robots=2)
    a, b = c["cloud-a"], c["cloud-b"]
    record, _ = a.store.create_request("app", {})
    pairs = [("a-0", "cloud-a"), ("b-0", "cloud-b"), ("b-1", "cloud-b")]
    assert a.view.reserve(record.id, pairs) == []
    a.view.release(record.id, [("b-0", "cloud-b")], "refused")
    assert [loan.robot for loan in b.store.loans()] == ["b-1"]
    a.view.release(record.id, None)  # this cloud's holds only
    assert a.store.reservations() == {}
    assert [loan.robot for loan in b.store.loans()] == ["b-1"]
    a.view.release(record.id, pairs, "canceled")
    assert b.store.loans() == []
    a.view.release(record.id, pairs, "canceled")  # again: harmless


def test_a_robot_reserved_here_is_reserved_at_once_for_selections() -> None:
    """The cached read of the store's reservations does not hide a reservation made here."""
    _, c = clouds(("cloud-a",), robots=2)
    a = c["cloud-a"]
    assert {r.id: r.status for r in a.view.local_robots()} == {"a-0": "idle", "a-1": "idle"}
    rid, _ = a.store.create_request("app", {})
    # The read above is still served (RESERVATIONS_TTL); the reservation shows anyway.
    assert a.view.reserve(rid.id, [("a-0", "cloud-a")]) == []
    assert {r.id: r.status for r in a.view.local_robots()} == {"a-0": "reserved", "a-1": "idle"}


def idle_questions(network: MemoryNetwork) -> int:
    return sum(name == "idle" for _, _, name in network.calls)


def test_an_answer_serves_selections_of_the_same_filter_for_a_quarter_second() -> None:
    time = FakeTime()
    network, c = clouds(("cloud-a", "cloud-b"), robots=2, time=time)
    view = c["cloud-a"].view
    assert len(view.remote_robots(TASK, exclude=set()).robots) == 2
    assert view.remote_robots(TASK, exclude={"b-0"}).gather_ms == 0.0  # not asked
    assert [r.id for r in view.remote_robots(TASK, exclude={"b-0"}).robots] == ["b-1"]
    assert idle_questions(network) == 1
    other = TASK.model_copy(update={"min_battery": 80.0})  # another filter: asked
    view.remote_robots(other, exclude=set())
    assert idle_questions(network) == 2
    time.advance(GATHER_TTL)
    view.remote_robots(TASK, exclude=set())
    assert idle_questions(network) == 3
    # An answer with a cloud missing is not kept.
    c3 = clouds(("cloud-a", "cloud-b", "cloud-c"), robots=1, time=time)
    network3, view3 = c3[0], c3[1]["cloud-a"].view
    network3.mute("cloud-c")
    assert view3.remote_robots(TASK, exclude=set()).notes
    network3.mend("cloud-c")
    assert view3.remote_robots(TASK, exclude=set()).notes == []
    assert idle_questions(network3) == 4  # twice to each of two clouds


def test_a_robot_lent_meanwhile_is_refused_and_the_next_selection_asks_again() -> None:
    time = FakeTime()
    network, c = clouds(("cloud-a", "cloud-b", "cloud-c"), robots=2, time=time)
    a, cc = c["cloud-a"], c["cloud-c"]
    assert "b-0" in [r.id for r in a.view.remote_robots(TASK, exclude=set()).robots]
    assert cc.view.reserve("req-c", [("b-0", "cloud-b")]) == []  # lent to cloud-c meanwhile
    kept = [r.id for r in a.view.remote_robots(TASK, exclude=set()).robots]
    assert "b-0" in kept  # the kept answer still offers it ...
    rid, _ = a.store.create_request("app", {})
    assert a.view.reserve(rid.id, [("b-0", "cloud-b")]) == ["b-0"]  # ... its home refuses it
    fresh = [r.id for r in a.view.remote_robots(TASK, exclude=set()).robots]
    assert "b-0" not in fresh  # asked again at once, not a quarter second later
    assert idle_questions(network) == 4  # two clouds, twice


def test_robots_this_cloud_holds_are_no_candidates_even_in_a_kept_answer() -> None:
    _, c = clouds(("cloud-a", "cloud-b"), robots=2)
    a = c["cloud-a"]
    others = a.view.remote_robots(TASK, exclude=set()).robots
    found = a.view.candidates(TASK, {"b-0", "a-1"}, others)
    assert found.problem.ids == ("a-0", "b-1")


def test_a_robot_on_its_way_back_home_is_not_offered_from_a_kept_answer() -> None:
    import threading

    time = FakeTime()
    _, c = clouds(("cloud-a", "cloud-b"), robots=2, time=time)
    a, b = c["cloud-a"], c["cloud-b"]
    assert sorted(r.id for r in a.view.remote_robots(TASK, exclude=set()).robots) == ["b-0", "b-1"]
    rid, _ = a.store.create_request("app", {})
    assert a.view.reserve(rid.id, [("b-0", "cloud-b")]) == []
    # The home is slow to take b-0 back: while the cancel travels, a selection
    # here (its request is over, so b-0 is no longer held) must not get b-0
    # from the answer kept from before it was lent.
    arrived, go_on = threading.Event(), threading.Event()
    cancel = b.home.cancel

    def slow_cancel(origin: str, release: object) -> object:
        arrived.set()
        go_on.wait(5)
        return cancel(origin, release)  # type: ignore[arg-type]

    b.home.cancel = slow_cancel  # type: ignore[method-assign]
    stopping = threading.Thread(target=a.view.cancel, args=("b-0", "cloud-b", rid.id))
    stopping.start()
    assert arrived.wait(5)
    assert [r.id for r in a.view.remote_robots(TASK, exclude=set()).robots] == ["b-1"]
    go_on.set()
    stopping.join(5)
    time.advance(GATHER_TTL)  # back home: its home's next answer offers it
    assert sorted(r.id for r in a.view.remote_robots(TASK, exclude=set()).robots) == ["b-0", "b-1"]


def test_a_robot_borrowed_since_an_answer_was_asked_is_not_offered_from_it() -> None:
    time = FakeTime()
    network, c = clouds(("cloud-a", "cloud-b"), robots=2, time=time)
    a = c["cloud-a"]
    assert sorted(r.id for r in a.view.remote_robots(TASK, exclude=set()).robots) == ["b-0", "b-1"]
    rid, _ = a.store.create_request("app", {})
    assert a.view.reserve(rid.id, [("b-0", "cloud-b")]) == []
    a.view.cancel("b-0", "cloud-b", rid.id)  # given back: idle at home again
    a.view.release(rid.id, [("b-0", "cloud-b")], "done")
    # The kept answer said b-0 was idle before it worked here; it cannot say
    # whether b-0 is idle now (a robot just stopped may not be), so it no
    # longer offers it. Its home's next answer does.
    assert [r.id for r in a.view.remote_robots(TASK, exclude=set()).robots] == ["b-1"]
    assert idle_questions(network) == 1  # still the kept answer
    time.advance(GATHER_TTL)
    assert sorted(r.id for r in a.view.remote_robots(TASK, exclude=set()).robots) == ["b-0", "b-1"]
    assert idle_questions(network) == 2


def test_candidates_at_hand_never_read_the_store_and_equal_candidates_while_a_read_serves(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import robocloud.federation.view as view_module

    now = [1000.0]
    monkeypatch.setattr(view_module, "time", SimpleNamespace(monotonic=lambda: now[0]))
    _, c = clouds(("cloud-a",), robots=3)
    a = c["cloud-a"]
    reads = []
    real = a.store.reservations
    monkeypatch.setattr(a.store, "reservations", lambda: reads.append(1) or real())
    assert a.view.candidates_at_hand(TASK) is None  # nothing read yet: a thread must read
    assert reads == []
    assert a.view.candidates(TASK).problem.ids == ("a-0", "a-1", "a-2")
    assert reads == [1]
    rid, _ = a.store.create_request("app", {})
    assert a.view.reserve(rid.id, [("a-1", "cloud-a")]) == []
    at_hand = a.view.candidates_at_hand(TASK, {"a-2"})
    assert at_hand is not None and at_hand.problem.ids == ("a-0",)  # just reserved, left out
    assert reads == [1]
    now[0] += RESERVATIONS_TTL  # the read is too old now
    assert a.view.candidates_at_hand(TASK) is None and reads == [1]
    assert a.view.candidates(TASK).problem.ids == ("a-0", "a-2")
    assert reads == [1, 1]
