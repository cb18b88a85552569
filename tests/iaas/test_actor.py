"""The actor shell around the pure life cycle: what it does at the edges of its life."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest

from robocloud.domain import Robot, Task
from robocloud.errors import Conflict
from robocloud.federation.view import FederationView
from robocloud.fleet import MemoryRobotLink
from robocloud.iaas import lifecycle as lc
from robocloud.iaas.actor import Inbox, RequestActor, Shell
from robocloud.iaas.routes import RobotRoutes
from robocloud.selection.pipeline import select_problem
from robocloud.storage import MemoryRequestStore, StoreUnavailable

TASK = {
    "location": [0.0, 0.0],
    "actuating": {"grabber": 1},
    "max_robots": 1,
    "max_cost": 10.0,
    "max_time": 10.0,
}


def shell_for(store: MemoryRequestStore) -> Shell:
    link = MemoryRobotLink("cloud-a")

    async def call(function: Any, *args: Any) -> Any:
        return function(*args)

    async def no_selection(*_: Any) -> Any:
        raise AssertionError("no selection expected")

    return Shell(
        store=store,
        view=FederationView("cloud-a", store, link),
        selector=no_selection,
        rules=lc.Rules(),
        blocking=call,
        store_write=call,
        publish=lambda _: None,
        routes=RobotRoutes(),
    )


def _idle_grabber(robot_id: str, x: float) -> Robot:
    return Robot.model_validate(
        {
            "id": robot_id, "cloud": "cloud-a", "position": [x, 0.0], "speed": 1.0,
            "battery": 90.0, "status": "idle", "travel_cost_per_m": 0.1,
            "capabilities": {"grabber": {"kind": "actuating", "time": 1.0, "cost": 1.0}},
        }
    )  # fmt: skip


def test_a_cancel_posted_after_the_actor_ended_is_answered_at_once() -> None:
    store = MemoryRequestStore()
    record, _ = store.create_request("app", TASK)
    record = store.transition(record.id, "selecting")
    record = store.transition(record.id, "rejected", "nothing fits")
    life = lc.Life(record.id, Task.model_validate(TASK), state="rejected")

    async def main() -> tuple[bool, Any]:
        actor = RequestActor(shell_for(store), life, record)
        await actor.run(lc.Start())  # already final: the actor ends at once
        reply: asyncio.Future[Any] = asyncio.get_running_loop().create_future()
        actor.post(lc.CancelAsked(), reply)  # as the service may, before it forgets the actor
        return reply.done(), reply.result() if reply.done() else None

    done, answer = asyncio.run(main())
    assert done, "the cancel would wait for an actor that is gone"
    assert answer.state == "rejected"


def test_commands_are_timed_as_acks_here_and_as_overlay_calls_for_other_clouds() -> None:
    store = MemoryRequestStore()
    record, _ = store.create_request("app", TASK)
    shell = shell_for(store)
    shell.view.link.put(_idle_grabber("a-1", 1.0))  # type: ignore[attr-defined]
    members = [
        lc.Member(robot, cloud, ("grabber",), 1.0, 1.0)
        for robot, cloud in (("a-1", "cloud-a"), ("b-1", "cloud-b"))
    ]
    life = lc.Life(record.id, Task.model_validate(TASK))

    async def main() -> Any:
        actor = RequestActor(shell, life, record)
        acked = await actor._assign(members, Task.model_validate(TASK))
        await actor._stop((("a-1", "cloud-a"),))
        return acked

    acked = asyncio.run(main())
    assert set(acked.refused) == {"b-1"}  # no overlay: cloud-b cannot be reached
    registry = shell.metrics.registry
    for name, labels in (
        ("robocloud_command_ack_seconds_count", {"command": "assign"}),
        ("robocloud_command_ack_seconds_count", {"command": "stop"}),
        ("robocloud_overlay_seconds_count", {"operation": "dispatch"}),
    ):
        assert registry.get_sample_value(name, labels) == 1, name
    cancels = registry.get_sample_value("robocloud_overlay_seconds_count", {"operation": "cancel"})
    assert cancels is None  # the stop went to this cloud's robot only



def _two_selections_at_once(turns: int | None) -> list[str]:
    """Two requests select at once; the robot each chose (a-1 is nearer for both)."""
    store = MemoryRequestStore()
    shell = shell_for(store)
    shell.view.link.put(_idle_grabber("a-1", 1.0))  # type: ignore[attr-defined]
    shell.view.link.put(_idle_grabber("a-2", 2.0))  # type: ignore[attr-defined]
    claims: dict[str, str] = {}
    shell.held = lambda: claims.keys()
    shell.claim = lambda rid, robots: claims.update((r, rid) for r in robots)

    async def in_a_worker(problem: Any, task: Task) -> Any:
        await asyncio.sleep(0.02)  # the worker's time, while the other request waits
        return select_problem(problem, task, "exact", ranking=False)

    shell.selector = in_a_worker
    task = Task.model_validate(TASK)

    async def main() -> list[str]:
        if turns is not None:
            semaphore = asyncio.Semaphore(turns)
            shell.selection_turn = lambda: semaphore
        records = [store.create_request("app", TASK)[0] for _ in range(2)]
        actors = [RequestActor(shell, lc.Life(r.id, task), r) for r in records]
        selected = await asyncio.gather(
            *(actor._select(lc.Select(task, frozenset())) for actor in actors)
        )
        return [s.chosen[0].robot for s in selected]  # type: ignore[attr-defined]

    return asyncio.run(main())


def test_a_selection_reads_its_candidates_in_its_turn_not_before() -> None:
    # One turn at a time: the second reads its candidates after the first claimed a-1.
    assert _two_selections_at_once(turns=1) == ["a-1", "a-2"]
    # Without turns both read them before either chose, and both choose a-1: one
    # of the two reservations would then find it taken and select again.
    assert _two_selections_at_once(turns=None) == ["a-1", "a-1"]


def test_the_inbox_gives_letters_in_order_and_a_tick_when_none_came() -> None:
    async def main() -> list[Any]:
        inbox = Inbox()
        inbox.put_nowait((lc.CancelAsked(), None))
        first = await inbox.next(10.0)  # waiting already: no wait
        waiting = asyncio.ensure_future(inbox.next(10.0))
        await asyncio.sleep(0)
        inbox.put_nowait((None, None))  # wakes the waiting one
        inbox.put_nowait((lc.Tick(), None))
        second = await asyncio.wait_for(waiting, 5)
        third = await inbox.next(10.0)
        none_came = await inbox.next(0.01)
        return [first[0], second[0], third[0], none_came[0], inbox.empty()]

    first, second, third, none_came, empty = asyncio.run(main())
    assert isinstance(first, lc.CancelAsked)
    assert second is None
    assert isinstance(third, lc.Tick) and isinstance(none_came, lc.Tick)
    assert empty


class AnswerLost(MemoryRequestStore):
    """A store whose first move to ``selecting`` and first note are stored and then fail
    as unavailable: the connection broke after the commit, before its answer."""

    def __init__(self) -> None:
        super().__init__()
        self.lost = 0
        self.notes_lost = 0

    def transition(self, request_id: str, new_state: str, *args: Any) -> Any:
        record = super().transition(request_id, new_state, *args)
        if new_state == "selecting" and not self.lost:
            self.lost += 1
            raise StoreUnavailable("The store at memory:// stopped answering.", "memory://")
        return record

    def add_event(self, request_id: str, detail: str) -> Any:
        record = super().add_event(request_id, detail)
        if not self.notes_lost:
            self.notes_lost += 1
            raise StoreUnavailable("The store at memory:// stopped answering.", "memory://")
        return record


def test_a_state_change_stored_by_a_try_that_lost_its_answer_is_not_a_conflict() -> None:
    store = AnswerLost()
    record, _ = store.create_request("app", TASK)
    life = lc.Life(record.id, Task.model_validate(TASK))

    async def main() -> tuple[Any, Any]:
        actor = RequestActor(shell_for(store), life, record)
        await actor._carry_out(lc.Commit("selecting", None, None, None))
        moved = actor.record
        # A move the request's state refuses, with no try lost before it, is still one.
        with pytest.raises(Conflict):
            await actor._carry_out(lc.Commit("completed", None, None, None))
        return moved, store.get(record.id)

    moved, stored = asyncio.run(main())
    assert store.lost == 1  # the first try was stored, its answer lost
    assert moved.state == "selecting" and stored.state == "selecting"
    assert [h.state for h in stored.history] == ["received", "selecting"]  # stored once


def test_a_note_stored_by_a_try_that_lost_its_answer_is_not_written_again() -> None:
    store = AnswerLost()
    record, _ = store.create_request("app", TASK)
    life = lc.Life(record.id, Task.model_validate(TASK))

    async def main() -> Any:
        actor = RequestActor(shell_for(store), life, record)
        await actor._carry_out(lc.Note("robot a-0003 failed; replaced by a-0017"))
        # The same words later are a new line: only a lost answer's retry is skipped.
        await actor._carry_out(lc.Note("robot a-0003 failed; replaced by a-0017"))
        return actor.record

    record = asyncio.run(main())
    assert store.notes_lost == 1
    notes = [h.detail for h in store.get(record.id).history if h.kind == "event"]
    assert notes == ["robot a-0003 failed; replaced by a-0017"] * 2  # not three
    assert record.history == store.get(record.id).history
