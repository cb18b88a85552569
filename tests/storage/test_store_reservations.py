"""Reservations: no robot is ever in two active coalitions, whoever races for it."""

from __future__ import annotations

import random
import threading

import pytest
from storage_testing import TASK, Backend, FakeClock, new_in

from robocloud.domain import FINAL_STATES
from robocloud.errors import Conflict, InvalidInput, NotFound
from robocloud.storage import RequestStore


def test_reserve_is_all_or_nothing(store: RequestStore) -> None:
    first = new_in(store, "selecting")
    second = new_in(store, "selecting")
    assert store.reserve(first, ["a-1", "a-2"]) == []
    assert store.reserve(second, ["b-1", "a-2", "b-2", "a-1"]) == ["a-2", "a-1"]
    assert store.reservations() == {"a-1": first, "a-2": first}
    assert store.reserve(second, ["b-1", "b-2"]) == []
    assert store.reservations(second) == {"b-1": second, "b-2": second}
    assert store.reservations(first) == {"a-1": first, "a-2": first}


def test_reserving_again_for_the_same_request_is_harmless(store: RequestStore) -> None:
    request_id = new_in(store, "selecting")
    assert store.reserve(request_id, ["a-1", "a-1"]) == []
    assert store.reserve(request_id, ["a-1", "a-2"]) == []
    assert store.reserve(request_id, []) == []
    assert store.reservations() == {"a-1": request_id, "a-2": request_id}


def test_release_some_or_all(store: RequestStore) -> None:
    mine = new_in(store, "selecting")
    theirs = new_in(store, "selecting")
    store.reserve(mine, ["a-1", "a-2", "a-3"])
    store.reserve(theirs, ["b-1"])
    store.release(mine, ["a-2", "b-1"])  # b-1 is not mine: untouched
    assert store.reservations() == {"a-1": mine, "a-3": mine, "b-1": theirs}
    store.release(mine)
    assert store.reservations() == {"b-1": theirs}
    store.release("req-nosuchrequest")  # releasing is always safe


def test_replace_swaps_one_robot(store: RequestStore) -> None:
    mine = new_in(store, "underway")
    theirs = new_in(store, "selecting")
    store.reserve(mine, ["a-1", "a-2"])
    store.reserve(theirs, ["b-1"])
    assert store.replace(mine, "a-1", "b-1") == ["b-1"]
    assert store.reservations(mine) == {"a-1": mine, "a-2": mine}
    assert store.replace(mine, "a-1", "a-9") == []
    assert store.reservations(mine) == {"a-2": mine, "a-9": mine}


@pytest.mark.parametrize("final", sorted(FINAL_STATES))
def test_a_final_state_releases_every_robot(store: RequestStore, final: str) -> None:
    before = {
        "completed": "underway",
        "rejected": "selecting",
        "canceled": "dispatched",
        "failed": "dispatched",
    }[final]
    request_id = new_in(store, before)
    other = new_in(store, "selecting")
    store.reserve(request_id, ["a-1", "a-2"])
    store.reserve(request_id, ["a-3"], lease_seconds=60)
    store.reserve(other, ["b-1"])
    store.transition(request_id, final)
    assert store.reservations() == {"b-1": other}
    with pytest.raises(Conflict, match=rf"^Request {request_id} is {final}; it cannot reserve"):
        store.reserve(request_id, ["a-1"])
    with pytest.raises(Conflict):
        store.confirm(request_id, ["a-1"])
    with pytest.raises(Conflict):
        store.replace(request_id, "a-1", "a-4")
    assert store.reserve(other, ["a-1", "a-2", "a-3"]) == []


def test_reserve_refuses_bad_input(store: RequestStore) -> None:
    request_id = new_in(store, "selecting")
    with pytest.raises(NotFound):
        store.reserve("req-nosuchrequest", ["a-1"])
    with pytest.raises(InvalidInput, match="robot_ids must be a list"):
        store.reserve(request_id, "a-1")
    with pytest.raises(InvalidInput, match="robot id"):
        store.reserve(request_id, ["a-1", ""])
    for lease in (0, -1, float("nan"), float("inf")):
        with pytest.raises(InvalidInput, match="lease_seconds"):
            store.reserve(request_id, ["a-1"], lease_seconds=lease)
    assert store.reservations() == {}


def test_leases_lapse_unless_confirmed(backend: Backend, clock: FakeClock) -> None:
    store = backend.open(clock)
    first = new_in(store, "selecting")
    second = new_in(store, "selecting")
    assert store.reserve(first, ["a-1", "a-2"], lease_seconds=30) == []
    assert store.reserve(second, ["a-2"], lease_seconds=30) == ["a-2"]
    clock.advance(20)
    assert store.confirm(first, ["a-1"]) == []  # a-1 firm; a-2 still a lease
    clock.advance(20)
    assert store.reservations() == {"a-1": first}  # a lapsed lease is not shown...
    assert store.reserve(second, ["a-2", "a-3"], lease_seconds=30) == []  # ...and is free
    assert store.reservations() == {"a-1": first, "a-2": second, "a-3": second}
    clock.advance(3600)
    assert store.reservations() == {"a-1": first}
    # A lapsed lease nobody took is taken back by confirming it.
    assert store.confirm(second, ["a-2"]) == []
    clock.advance(3600)
    assert store.reservations() == {"a-1": first, "a-2": second}


def test_leases_are_extended_never_shortened(backend: Backend, clock: FakeClock) -> None:
    store = backend.open(clock)
    mine = new_in(store, "selecting")
    theirs = new_in(store, "selecting")
    store.reserve(mine, ["a-1"], lease_seconds=100)
    store.reserve(mine, ["a-1"], lease_seconds=10)
    clock.advance(50)
    assert store.reserve(theirs, ["a-1"]) == ["a-1"]
    store.reserve(mine, ["a-1"], lease_seconds=100)
    clock.advance(99)
    assert store.reservations() == {"a-1": mine}
    store.reserve(mine, ["a-1"])  # firm
    store.reserve(mine, ["a-1"], lease_seconds=1)  # stays firm
    clock.advance(10_000)
    assert store.reserve(theirs, ["a-1"]) == ["a-1"]


def race_to_reserve(
    stores: tuple[RequestStore, RequestStore], threads: int, robots: int, size: int, seed: int
) -> None:
    """``threads`` requests reserve random overlapping sets at once; check the outcome."""
    rng = random.Random(seed)
    fleet = [f"r-{i:02d}" for i in range(robots)]
    requests = [new_in(stores[0], "selecting") for _ in range(threads)]
    wanted = {request_id: rng.sample(fleet, size) for request_id in requests}
    barrier = threading.Barrier(threads)
    outcome: dict[str, list[str]] = {}
    errors: list[BaseException] = []

    def reserve(index: int, request_id: str) -> None:
        try:
            barrier.wait()
            outcome[request_id] = stores[index % 2].reserve(request_id, wanted[request_id])
        except BaseException as error:  # reported below
            errors.append(error)

    workers = [
        threading.Thread(target=reserve, args=(index, request_id))
        for index, request_id in enumerate(requests)
    ]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join()
    assert errors == [], errors

    winners = [request_id for request_id in requests if outcome[request_id] == []]
    assert winners, "somebody must win"
    expected: dict[str, str] = {}
    for request_id in winners:
        for robot in wanted[request_id]:
            assert robot not in expected, f"{robot} reserved twice"
            expected[robot] = request_id
    for store in stores:
        assert store.reservations() == expected
    for request_id in requests:
        taken = outcome[request_id]
        if taken:
            # A loser names only robots a winner holds, and holds nothing itself.
            assert set(taken) <= set(wanted[request_id])
            assert all(expected[robot] != request_id for robot in taken)
            assert store.reservations(request_id) == {}


@pytest.mark.parametrize("seed", [1, 2])
def test_twenty_threads_never_double_book(backend: Backend, seed: int) -> None:
    race_to_reserve(backend.pair(), threads=20, robots=30, size=5, seed=seed)


def test_racing_for_one_robot_has_one_winner(backend: Backend) -> None:
    race_to_reserve(backend.pair(), threads=20, robots=5, size=5, seed=0)


def test_two_stores_on_one_database_cannot_double_book(sql_backend: Backend) -> None:
    first, second = sql_backend.open(), sql_backend.open()
    mine, _ = first.create_request("wildfire", TASK)
    theirs, _ = second.create_request("patrol", TASK)
    assert first.reserve(mine.id, ["a-1", "a-2"]) == []
    assert second.reserve(theirs.id, ["a-2", "a-3"]) == ["a-2"]
    assert second.reservations() == {"a-1": mine.id, "a-2": mine.id}
    second.transition(mine.id, "canceled")
    assert first.reservations() == {}
    assert first.reserve(theirs.id, ["a-2", "a-3"]) == []
    assert second.get(theirs.id) == first.get(theirs.id)
