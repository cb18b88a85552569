"""A robot set aside for failing is chosen by no one: not by its origin, not through its home.

A cloud sets aside a robot that failed its requests twice in a row
(``RobotRoutes``). The robot may be the cloud's own or another's: the cloud's
selections leave it out either way, and its home lends it to no other cloud.
"""

from __future__ import annotations

from federation_testing import candidates_seen, clouds

from robocloud.federation.messages import Reservation
from robocloud.iaas.routes import RobotRoutes


class Wall:
    """The routes' wall clock, moved by hand."""

    def __init__(self) -> None:
        self.now = 1_000_000.0

    def __call__(self) -> float:
        return self.now


def set_aside(routes: RobotRoutes, robot: str) -> None:
    routes.strike(robot, "robot did not answer within the ack deadline (1 s)")
    assert routes.strike(robot, "no progress for 30 s") is not None


def test_a_robot_of_another_cloud_the_origin_set_aside_is_not_among_its_candidates() -> None:
    """cloud-b offers b-0 (it knows nothing of cloud-a's record), and cloud-a leaves it out."""
    _, c = clouds(("cloud-a", "cloud-b"), robots=2)
    routes = RobotRoutes()
    assert candidates_seen(c["cloud-a"], routes) == [("a-0", "a-1", "b-0", "b-1")]
    set_aside(routes, "b-0")
    assert candidates_seen(c["cloud-a"], routes) == [("a-0", "a-1", "b-1")]
    assert c["cloud-b"].store.loans() == []


def test_a_home_neither_offers_nor_lends_a_robot_it_set_aside() -> None:
    wall = Wall()
    b_routes = RobotRoutes(cooldown=300.0, wall=wall)
    network, c = clouds(("cloud-a", "cloud-b"), robots=2, set_aside={"cloud-b": b_routes.aside})
    a, b = c["cloud-a"], c["cloud-b"]
    set_aside(b_routes, "b-0")

    # Not offered: cloud-a's selection never sees it.
    assert candidates_seen(a) == [("a-0", "a-1", "b-1")]
    assert network.calls.count(("cloud-a", "cloud-b", "idle")) == 1

    # Not lent, though asked by name: the refusal says why, and nothing is stored.
    reply = a.overlay.reserve("cloud-b", Reservation(request_id="req-1", robots=["b-1", "b-0"]))
    assert reply.taken == ["b-1", "b-0"]
    assert reply.error == (
        "cloud-b has set b-0 aside and lends it to no one now: it failed 2 requests in a "
        "row: robot did not answer within the ack deadline (1 s); no progress for 30 s."
    )
    assert b.store.loans() == []

    # Once its cool-down is over it is offered and lent again.
    wall.now += 301.0
    a.view.forget_gathered()
    assert candidates_seen(a) == [("a-0", "a-1", "b-0", "b-1")]
    reply = a.overlay.reserve("cloud-b", Reservation(request_id="req-1", robots=["b-0"]))
    assert reply.taken == [] and reply.error is None
    assert [loan.robot for loan in b.store.loans()] == ["b-0"]
