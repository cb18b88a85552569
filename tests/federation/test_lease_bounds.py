"""Leases with hard bounds, written as the attacker would: a trusted cloud (cloud-c) that
reserves every robot of cloud-b, busy and charging ones included, for a day, again and again.

Clouds in memory (``federation_testing``), on one fake clock.
"""

from __future__ import annotations

import logging

import pytest
from federation_testing import Cloud, FakeTime, clouds

from robocloud.federation.lending import RESERVE_BURST
from robocloud.federation.memory import MemoryNetwork
from robocloud.federation.messages import Release, Reservation

LEASE_MAX = 30.0


@pytest.fixture
def time() -> FakeTime:
    return FakeTime()


@pytest.fixture
def fed(time: FakeTime) -> tuple[MemoryNetwork, dict[str, Cloud]]:
    return clouds(
        ("cloud-a", "cloud-b", "cloud-c"),
        robots=6,
        trust={"cloud-b": ["cloud-a", "cloud-c"]},
        time=time,
        lease_max=LEASE_MAX,
        lend_share=0.5,
    )


def day_long(request_id: str, robots: list[str]) -> Reservation:
    return Reservation(request_id=request_id, robots=robots, lease_seconds=86400)


def report_again(b: Cloud) -> None:
    """cloud-b's robots report (each robot sends a state every second or so)."""
    for state in b.link.states().values():
        b.link.put(state)


def test_renewals_do_not_extend_a_lease_past_lease_max(
    fed: tuple[MemoryNetwork, dict[str, Cloud]], time: FakeTime, caplog: pytest.LogCaptureFixture
) -> None:
    """Re-reserving every 10 s, under new request ids, releasing in between: 30 s at most."""
    _, c = fed
    b, attacker = c["cloud-b"], c["cloud-c"]
    robots = ["b-0", "b-1"]
    assert attacker.overlay.reserve("cloud-b", day_long("req-0", robots)).taken == []
    for n in range(1, 3):
        time.advance(10)
        report_again(b)
        if n == 2:
            attacker.overlay.release("cloud-b", Release(request_id="req-0"))
        request_id = "req-0" if n == 1 else f"req-{n}"
        assert attacker.overlay.reserve("cloud-b", day_long(request_id, robots)).taken == []
        loan = b.store.loan_of("b-0")
        assert loan is not None and loan.expires_at is not None
        granted = (loan.expires_at - time.utc()).total_seconds()
        assert granted == pytest.approx(LEASE_MAX - 10 * n, abs=0.01)
    time.advance(10)
    report_again(b)
    attacker.overlay.release("cloud-b", Release(request_id="req-2"))
    reply = attacker.overlay.reserve("cloud-b", day_long("req-3", robots))
    assert reply.taken == robots
    assert "leases at most 30 s until the dispatch, renewals included" in (reply.error or "")
    time.advance(1)
    b.reconciler.reconcile()  # the lapsed leases end
    assert b.home.lent_for("b-0") is None and b.home.lent_for("b-1") is None
    assert "refused a reserve from cloud-c for request req-3" in caplog.text
    # Another origin is not held back; the attacker again once a lease_max has passed.
    assert c["cloud-a"].overlay.reserve("cloud-b", day_long("req-a", ["b-0"])).taken == []
    time.advance(LEASE_MAX + 1)
    report_again(b)
    assert attacker.overlay.reserve("cloud-b", day_long("req-4", ["b-1"])).taken == []


def test_only_idle_robots_with_battery_are_lent(
    fed: tuple[MemoryNetwork, dict[str, Cloud]],
) -> None:
    _, c = fed
    b, attacker = c["cloud-b"], c["cloud-c"]
    robots = {r.id: r for r in b.link.robots()}
    b.link.put(robots["b-1"].model_copy(update={"status": "charging"}))
    b.link.put(robots["b-2"].model_copy(update={"battery": 5.0}))
    for robot, why in [("b-1", "b-1 is charging"), ("b-2", "b-2 has 5% of battery")]:
        reply = attacker.overlay.reserve("cloud-b", day_long(f"req-{robot}", [robot]))
        assert reply.taken == [robot]
        assert "only idle robots with at least 20% of battery are lent" in (reply.error or "")
        assert why in (reply.error or "")
        assert b.home.lent_for(robot) is None


def test_an_origin_holds_at_most_its_share_of_the_fleet(
    fed: tuple[MemoryNetwork, dict[str, Cloud]],
) -> None:
    _, c = fed
    attacker, other = c["cloud-c"], c["cloud-a"]
    everyone = [f"b-{i}" for i in range(6)]
    reply = attacker.overlay.reserve("cloud-b", day_long("req-all", everyone))
    assert reply.taken == everyone
    assert "cloud-c holds 0 of cloud-b's 6 robots and asks 6 more" in (reply.error or "")
    assert "at most 50% of its robots (3)" in (reply.error or "")
    assert attacker.overlay.reserve("cloud-b", day_long("req-1", everyone[:3])).taken == []
    assert attacker.overlay.reserve("cloud-b", day_long("req-2", everyone[3:4])).taken
    # The share is per origin: cloud-a still gets the rest.
    assert other.overlay.reserve("cloud-b", day_long("req-a", everyone[3:6])).taken == []


def test_reservations_beyond_the_rate_are_refused(
    fed: tuple[MemoryNetwork, dict[str, Cloud]], time: FakeTime, caplog: pytest.LogCaptureFixture
) -> None:
    _, c = fed
    attacker = c["cloud-c"]
    caplog.set_level(logging.WARNING, "robocloud.federation.home")
    replies = [
        attacker.overlay.reserve("cloud-b", Reservation(request_id=f"req-{n}", robots=["b-0"]))
        for n in range(RESERVE_BURST + 5)
    ]
    refused = [r for r in replies if r.error and "reserves too often" in r.error]
    assert len(refused) >= 5
    assert "at most 50 reservations a second" in (refused[0].error or "")
    time.advance(1.0)  # the bucket fills again
    reply = attacker.overlay.reserve("cloud-b", Reservation(request_id="req-later", robots=["b-5"]))
    assert reply.error is None or "too often" not in reply.error
    assert "reserves too often" in caplog.text
