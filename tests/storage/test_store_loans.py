"""Loans: this cloud's robots lent to other clouds' requests, under the store's one guarantee.

A robot has one holder at a time, a request of this cloud or a loan, on every
backend and whoever races for it; a loan starts as a lease, becomes firm only
while its lease lives, and keeps its history once released.
"""

from __future__ import annotations

import random
import threading

import pytest
from storage_testing import Backend, FakeClock, new_in

from robocloud.errors import InvalidInput
from robocloud.storage import RequestStore


def held(store: RequestStore) -> dict[str, str]:
    """Robot -> holder, with loans shown as ``origin/request``."""
    loans = {loan.id: f"{loan.origin}/{loan.request_id}" for loan in store.loans()}
    return {robot: loans.get(holder, holder) for robot, holder in store.reservations().items()}


def test_a_robot_has_one_holder_a_request_or_a_loan(store: RequestStore) -> None:
    mine = new_in(store, "selecting")
    assert store.reserve(mine, ["b-1"]) == []
    assert store.lend("cloud-a", "req-a1", ["b-2", "b-1", "b-3"], 30) == ["b-1"]
    assert store.loans() == []  # all or nothing
    assert store.lend("cloud-a", "req-a1", ["b-2", "b-3"], 30) == []
    assert store.reserve(mine, ["b-3", "b-4"]) == ["b-3"]
    assert store.replace(mine, "b-1", "b-2") == ["b-2"]
    # Another request of the same origin, or another origin, is another holder.
    assert store.lend("cloud-a", "req-a2", ["b-2"], 30) == ["b-2"]
    assert store.lend("cloud-c", "req-a1", ["b-3"], 30) == ["b-3"]
    assert held(store) == {"b-1": mine, "b-2": "cloud-a/req-a1", "b-3": "cloud-a/req-a1"}
    holders = store.reservations()
    assert holders["b-2"].startswith("loan-") and holders["b-2"] != holders["b-3"]


def test_lending_again_to_the_same_request_is_harmless(backend: Backend, clock: FakeClock) -> None:
    store = backend.open(clock)
    assert store.lend("cloud-a", "req-a1", ["b-1"], 100) == []
    first = store.loan_of("b-1")
    assert first is not None
    assert store.lend("cloud-a", "req-a1", ["b-1", "b-1", "b-2"], 10) == []
    assert store.loan_of("b-1") == first  # the same loan; the lease is not shortened
    clock.advance(50)
    assert store.lend("cloud-a", "req-a1", ["b-1"], 100) == []  # extended to 150 s
    clock.advance(99)
    assert [loan.robot for loan in store.loans("cloud-a", "req-a1")] == ["b-1"]
    clock.advance(2)
    assert store.loans() == []


def test_a_confirm_needs_a_live_lease(backend: Backend, clock: FakeClock) -> None:
    store = backend.open(clock)
    # Never leased: refused, and nothing is taken.
    assert store.confirm_loans("cloud-a", "req-a1", ["b-1"]) == ["b-1"]
    assert store.reservations() == {}
    assert store.lend("cloud-a", "req-a1", ["b-1", "b-2"], 30) == []
    # All or nothing; another origin or request has no lease on them.
    assert store.confirm_loans("cloud-a", "req-a1", ["b-1", "b-3"]) == ["b-3"]
    assert store.confirm_loans("cloud-c", "req-a1", ["b-1"]) == ["b-1"]
    assert store.confirm_loans("cloud-a", "req-a2", ["b-1"]) == ["b-1"]
    assert {loan.state for loan in store.loans()} == {"leased"}
    assert store.confirm_loans("cloud-a", "req-a1", ["b-1"]) == []
    clock.advance(31)
    # b-2's lease lapsed: a confirm does not bring it back.
    assert store.confirm_loans("cloud-a", "req-a1", ["b-2"]) == ["b-2"]
    assert held(store) == {"b-1": "cloud-a/req-a1"}
    firm = store.loan_of("b-1")
    assert firm is not None and firm.state == "firm" and firm.expires_at is None
    assert [(h.state, h.detail) for h in firm.history] == [
        ("leased", "lent to cloud-a"),
        ("firm", "confirmed"),
    ]
    clock.advance(10_000)
    assert store.confirm_loans("cloud-a", "req-a1", ["b-1"]) == []  # firm stays firm
    assert store.lend("cloud-a", "req-a1", ["b-1"], 1) == []
    clock.advance(10)
    assert held(store) == {"b-1": "cloud-a/req-a1"}


def test_a_firm_loan_no_longer_lapses(backend: Backend, clock: FakeClock) -> None:
    store = backend.open(clock)
    assert store.lend("cloud-a", "req-a1", ["b-1", "b-2"], 30) == []
    assert store.confirm_loans("cloud-a", "req-a1", ["b-1"]) == []
    firm = store.loan_of("b-1")
    clock.advance(3600)
    assert [loan.robot for loan in store.lapse_loans()] == ["b-2"]
    assert store.confirm_loans("cloud-a", "req-a1", ["b-1"]) == []  # again: nothing changes
    assert store.loan_of("b-1") == firm
    assert firm is not None and [(h.state, h.kind) for h in firm.history] == [
        ("leased", "state"),
        ("firm", "state"),
    ]


def test_a_lapsed_lease_ends_whoever_notices(backend: Backend, clock: FakeClock) -> None:
    store = backend.open(clock)
    store.lend("cloud-a", "req-a1", ["b-1", "b-2"], 30)
    clock.advance(31)
    assert store.loan_of("b-1") is None
    # A request of this cloud takes b-1: its lapsed loan ends in that transaction.
    mine = new_in(store, "selecting")
    assert store.reserve(mine, ["b-1"]) == []
    ended = store.lapse_loans()
    assert [loan.robot for loan in ended] == ["b-2"]
    assert store.lapse_loans() == []
    assert held(store) == {"b-1": mine}
    assert store.end_loans("cloud-a", "req-a1", None, "too late") == []  # already over


def test_ending_loans_keeps_them_as_history(backend: Backend, clock: FakeClock) -> None:
    store = backend.open(clock)
    store.lend("cloud-a", "req-a1", ["b-1", "b-2", "b-3"], 30)
    store.lend("cloud-a", "req-a2", ["b-4"], 30)
    store.confirm_loans("cloud-a", "req-a1", ["b-1", "b-2", "b-3"])
    ended = store.end_loans("cloud-a", "req-a1", ["b-2", "b-4", "b-9"], "released by cloud-a")
    assert [(loan.robot, loan.state, loan.reason) for loan in ended] == [
        ("b-2", "released", "released by cloud-a")
    ]
    assert held(store) == {
        "b-1": "cloud-a/req-a1",
        "b-3": "cloud-a/req-a1",
        "b-4": "cloud-a/req-a2",
    }
    assert {loan.robot for loan in store.end_loans("cloud-a", "req-a1", None, "over")} == {
        "b-1",
        "b-3",
    }
    assert held(store) == {"b-4": "cloud-a/req-a2"}
    # The robots are free again, for a local request or another loan.
    mine = new_in(store, "selecting")
    assert store.reserve(mine, ["b-1"]) == []
    assert store.lend("cloud-c", "req-c1", ["b-2"], 30) == []


def test_loans_the_home_ends_wait_until_the_origin_is_told(store: RequestStore) -> None:
    store.lend("cloud-a", "req-a1", ["b-1", "b-2"], 30)
    store.lend("cloud-c", "req-c1", ["b-3"], 30)
    store.end_loans("cloud-a", "req-a1", ["b-1"], "released by cloud-a")
    away = "cloud-a was unreachable for 60 s"
    store.end_loans("cloud-a", "req-a1", ["b-2"], away, tell_origin=True)
    store.end_loans("cloud-c", "req-c1", None, away, tell_origin=True)
    untold = store.untold_loans("cloud-a")
    assert [(loan.robot, loan.reason, loan.tell_origin) for loan in untold] == [("b-2", away, True)]
    # Only the origin's own loans are marked, each once.
    assert store.told("cloud-a", [store.untold_loans("cloud-c")[0].id]) == []
    told = store.told("cloud-a", [untold[0].id, untold[0].id])
    assert [loan.id for loan in told] == [untold[0].id]
    assert store.untold_loans("cloud-a") == []
    assert store.told("cloud-a", [untold[0].id]) == []
    assert [loan.robot for loan in store.untold_loans("cloud-c")] == ["b-3"]
    assert store.loan_of("b-2") is None


def test_loans_are_found_by_robot_origin_and_request(store: RequestStore) -> None:
    store.lend("cloud-a", "req-a1", ["b-1", "b-2"], 30)
    store.lend("cloud-a", "req-a2", ["b-3"], 30)
    store.lend("cloud-c", "req-c1", ["b-4"], 30)
    assert [loan.robot for loan in store.loans()] == ["b-1", "b-2", "b-3", "b-4"]
    assert [loan.robot for loan in store.loans("cloud-a")] == ["b-1", "b-2", "b-3"]
    assert [loan.robot for loan in store.loans("cloud-a", "req-a2")] == ["b-3"]
    assert store.loans("cloud-c", "req-a2") == []
    loan = store.loan_of("b-4")
    assert loan is not None
    assert (loan.origin, loan.request_id, loan.state, loan.tell_origin) == (
        "cloud-c",
        "req-c1",
        "leased",
        False,
    )
    assert store.loan_of("b-9") is None
    assert all(loan.history == () for loan in store.loans())  # lists come without history


def test_an_origins_live_loans_are_counted(backend: Backend, clock: FakeClock) -> None:
    store = backend.open(clock)
    store.lend("cloud-a", "req-a1", ["b-1", "b-2"], 30)
    store.lend("cloud-a", "req-a2", ["b-3"], 60)
    store.lend("cloud-c", "req-c1", ["b-4"], 30)
    assert (store.count_loans("cloud-a"), store.count_loans("cloud-c")) == (3, 1)
    assert store.count_loans("cloud-z") == 0
    store.end_loans("cloud-a", "req-a1", ["b-1"], "released by cloud-a")
    assert store.count_loans("cloud-a") == 2
    store.confirm_loans("cloud-a", "req-a1", ["b-2"])
    clock.advance(45)  # req-a1's firm loan holds on, cloud-c's lease has lapsed
    assert (store.count_loans("cloud-a"), store.count_loans("cloud-c")) == (2, 0)
    assert store.count_loans("cloud-a") == len(store.loans("cloud-a"))


def test_loans_refuse_bad_input(store: RequestStore) -> None:
    with pytest.raises(InvalidInput, match="origin"):
        store.lend("", "req-a1", ["b-1"], 30)
    with pytest.raises(InvalidInput, match="request_id"):
        store.lend("cloud-a", "x" * 300, ["b-1"], 30)
    with pytest.raises(InvalidInput, match="robot_ids must be a list"):
        store.lend("cloud-a", "req-a1", "b-1", 30)
    for lease in (0, -1, float("nan"), float("inf"), None):
        with pytest.raises(InvalidInput, match="lease_seconds"):
            store.lend("cloud-a", "req-a1", ["b-1"], lease)  # type: ignore[arg-type]
    with pytest.raises(InvalidInput, match="why"):
        store.end_loans("cloud-a", "req-a1", None, " ")
    with pytest.raises(InvalidInput, match="loan id"):
        store.told("cloud-a", [""])
    assert store.reservations() == {}


def test_a_thousand_loans_made_and_released(store: RequestStore) -> None:
    """Every loan stays visible and releasable however many came before (no newest-N window)."""
    for i in range(1000):
        assert store.lend("cloud-a", f"req-{i:04d}", [f"b-{i:04d}"], 600) == []
    assert len(store.loans()) == 1000
    assert len(store.loans("cloud-a")) == 1000
    # The oldest loan is found by its robot and by its request, and ends.
    oldest = store.loan_of("b-0000")
    assert oldest is not None and oldest.request_id == "req-0000"
    for i in range(1000):
        ended = store.end_loans("cloud-a", f"req-{i:04d}", None, "released by cloud-a")
        assert [loan.robot for loan in ended] == [f"b-{i:04d}"]
    assert store.loans() == [] and store.reservations() == {}


def test_requests_and_loans_racing_never_share_a_robot(backend: Backend) -> None:
    """Twenty threads on two stores of one database: half reserve, half lend, overlapping."""
    stores = backend.pair()
    rng = random.Random(7)
    fleet = [f"b-{i:02d}" for i in range(12)]
    requests = [new_in(stores[0], "selecting") for _ in range(10)]
    jobs: list[tuple[str, str, list[str]]] = [
        ("reserve", r, rng.sample(fleet, 4)) for r in requests
    ]
    jobs += [("lend", f"req-a{i}", rng.sample(fleet, 4)) for i in range(10)]
    rng.shuffle(jobs)
    barrier = threading.Barrier(len(jobs))
    outcome: dict[str, list[str]] = {}
    errors: list[BaseException] = []

    def run(index: int, kind: str, holder: str, robots: list[str]) -> None:
        store = stores[index % 2]
        try:
            barrier.wait()
            if kind == "reserve":
                outcome[holder] = store.reserve(holder, robots)
            else:
                outcome[holder] = store.lend("cloud-a", holder, robots, 600)
        except BaseException as error:  # reported below
            errors.append(error)

    threads = [threading.Thread(target=run, args=(i, *job)) for i, job in enumerate(jobs)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert errors == [], errors
    expected: dict[str, str] = {}
    for kind, holder, robots in jobs:
        if outcome[holder] == []:
            for robot in robots:
                assert robot not in expected, f"{robot} has two holders"
                expected[robot] = holder if kind == "reserve" else f"cloud-a/{holder}"
        else:
            assert set(outcome[holder]) <= set(robots)
    assert expected, "somebody must win"
    for store in stores:
        assert held(store) == expected
