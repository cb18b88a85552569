"""Commands sent with a reservation: the home forwards them once every robot is lent.

The origin saves a round trip per coalition: the last home it reserves at
gets its robots' commands with the reservation and answers with their acks,
which the origin's ``assign`` then returns. What must hold: a robot is only
commanded once all of its home's robots are lent to the sender's request; a
robot commanded so and then given back (the request ended, or the
reservation was rolled back) is stopped; the lease then turns firm as after
a dispatch.
"""

from __future__ import annotations

from federation_testing import Cloud, clouds

from robocloud.federation.memory import MemoryNetwork
from robocloud.federation.messages import Dispatch, Reservation
from robocloud.fleet.messages import Assign, Cancel


def go(request_id: str) -> Assign:
    return Assign(request_id=request_id, location=[0.0, 0.0], capabilities=["grabber"])


def assigned(cloud: Cloud) -> list[tuple[str, str]]:
    return [(r, c.request_id) for r, c in cloud.link.commands if isinstance(c, Assign)]


def stopped(cloud: Cloud) -> list[tuple[str, str]]:
    return [(r, c.request_id) for r, c in cloud.link.commands if isinstance(c, Cancel)]


def sent(network: MemoryNetwork, name: str) -> int:
    return sum(n == name for _, _, n in network.calls)


def test_the_home_commands_its_robots_once_all_are_lent_and_the_lease_turns_firm() -> None:
    _, c = clouds(("cloud-a", "cloud-b", "cloud-c"), robots=2)
    a, b, cc = c["cloud-a"], c["cloud-b"], c["cloud-c"]
    both = Reservation(
        request_id="r1",
        robots=["b-0", "b-1"],
        dispatch=[Dispatch(robot=r, command=go("r1")) for r in ("b-0", "b-1")],
    )
    reply = a.overlay.reserve("cloud-b", both)
    assert reply.taken == [] and reply.error is None
    assert sorted((k.robot, k.ok) for k in reply.acks) == [("b-0", True), ("b-1", True)]
    assert sorted(assigned(b)) == [("b-0", "r1"), ("b-1", "r1")]
    # Dispatched by the home: the origin may make the leases firm.
    firm = a.overlay.confirm("cloud-b", Reservation(request_id="r1", robots=["b-0", "b-1"]))
    assert firm.taken == [] and firm.error is None
    # Another cloud's reservation of one of them: nothing lent, no robot commanded.
    clash = Reservation(
        request_id="r2", robots=["b-1"], dispatch=[Dispatch(robot="b-1", command=go("r2"))]
    )
    assert cc.overlay.reserve("cloud-b", clash).taken == ["b-1"]
    assert ("b-1", "r2") not in assigned(b)


def test_commands_that_do_not_fit_the_reservation_are_refused_and_nothing_is_lent() -> None:
    _, c = clouds(("cloud-a", "cloud-b"), robots=2)
    a, b = c["cloud-a"], c["cloud-b"]
    for dispatch in (
        [Dispatch(robot="b-1", command=go("r1"))],  # a robot not reserved
        [Dispatch(robot="b-0", command=go("other"))],  # another request's command
        [Dispatch(robot="b-0", command=go("r1"))] * 2,  # twice the same robot
    ):
        reply = a.overlay.reserve(
            "cloud-b", Reservation(request_id="r1", robots=["b-0"], dispatch=dispatch)
        )
        assert reply.taken == ["b-0"] and reply.error
    assert b.store.loans() == []
    assert assigned(b) == []


def test_the_view_sends_the_commands_to_the_last_home_and_assign_takes_their_acks() -> None:
    network, c = clouds(("cloud-a", "cloud-b", "cloud-c"), robots=2)
    a, b, cc = c["cloud-a"], c["cloud-b"], c["cloud-c"]
    rid, _ = a.store.create_request("app", {})
    pairs = [("c-0", "cloud-c"), ("a-0", "cloud-a"), ("b-0", "cloud-b")]
    commands = {r: go(rid.id) for r, _ in pairs}
    assert a.view.reserve(rid.id, pairs, commands) == []
    # This cloud first, then cloud-c; cloud-b, the last, got its robot's command.
    assert assigned(b) == [("b-0", rid.id)] and assigned(cc) == [] and assigned(a) == []
    assert a.view.assign("b-0", "cloud-b", go(rid.id)).ok
    assert sent(network, "dispatch") == 0  # no second command travelled
    assert a.view.assign("c-0", "cloud-c", go(rid.id)).ok  # sent now, as before
    assert sent(network, "dispatch") == 1
    assert a.view.take_ack(rid.id, "b-0") is None  # taken once


def test_a_rolled_back_reservation_commands_no_robot() -> None:
    _, c = clouds(("cloud-a", "cloud-b", "cloud-c"), robots=2)
    a, b, cc = c["cloud-a"], c["cloud-b"], c["cloud-c"]
    assert cc.view.reserve("req-c", [("b-1", "cloud-b")]) == []  # cloud-c holds b-1
    rid, _ = a.store.create_request("app", {})
    pairs = [("c-0", "cloud-c"), ("b-0", "cloud-b"), ("b-1", "cloud-b")]
    assert a.view.reserve(rid.id, pairs, {r: go(rid.id) for r, _ in pairs}) == ["b-1"]
    assert assigned(b) == [] and assigned(cc) == []
    assert cc.store.loans() == []  # cloud-c's robot was lent, then given back
    assert [loan.robot for loan in b.store.loans()] == ["b-1"]  # cloud-c's, untouched


def test_robots_commanded_with_a_reservation_and_given_back_are_stopped() -> None:
    _, c = clouds(("cloud-a", "cloud-b"), robots=2)
    a, b = c["cloud-a"], c["cloud-b"]
    rid, _ = a.store.create_request("app", {})
    pairs = [("b-0", "cloud-b"), ("b-1", "cloud-b")]
    assert a.view.reserve(rid.id, pairs, {r: go(rid.id) for r, _ in pairs}) == []
    assert len(assigned(b)) == 2
    # The request ended before its assign: what the actor's Release does then.
    a.view.release(rid.id, pairs, "the request is over")
    assert sorted(stopped(b)) == [("b-0", rid.id), ("b-1", rid.id)]
    assert b.store.loans() == []
    assert b.link.state("b-0").task is None  # type: ignore[union-attr]


def test_robots_commanded_by_a_reservation_whose_reply_was_lost_are_stopped() -> None:
    from robocloud.errors import RoboCloudError

    _, c = clouds(("cloud-a", "cloud-b"), robots=2)
    a, b = c["cloud-a"], c["cloud-b"]
    reserve = b.home.reserve

    def lost_reply(origin: str, reservation: Reservation) -> object:
        reserve(origin, reservation)  # lent and commanded at the home ...
        raise RoboCloudError("the reply was lost")  # ... but the origin never hears it

    b.home.reserve = lost_reply  # type: ignore[method-assign,assignment]
    rid, _ = a.store.create_request("app", {})
    pairs = [("b-0", "cloud-b")]
    assert a.view.reserve(rid.id, pairs, {"b-0": go(rid.id)}) == ["b-0"]
    assert assigned(b) == [("b-0", rid.id)]
    assert stopped(b) == [("b-0", rid.id)]  # told to stop at once
    assert b.store.loans() == []  # and not lent any more
    assert a.view.take_ack(rid.id, "b-0") is None
