"""The actor shell around the pure life cycle: what it does at the edges of its life."""

from __future__ import annotations

import asyncio
from typing import Any

from robocloud.domain import Robot, Task
from robocloud.federation.view import FederationView
from robocloud.fleet import MemoryRobotLink
from robocloud.iaas import lifecycle as lc
from robocloud.iaas.actor import RequestActor, Shell
from robocloud.storage import MemoryRequestStore

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
        follow=lambda *_: None,
        unfollow=lambda *_: None,
        publish=lambda _: None,
        held=lambda: (),
        claim=lambda *_: None,
        unclaim=lambda *_: None,
    )


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
    shell.view.link.put(  # type: ignore[attr-defined]
        Robot.model_validate(
            {
                "id": "a-1", "cloud": "cloud-a", "position": [1.0, 0.0], "speed": 1.0,
                "battery": 90.0, "status": "idle", "travel_cost_per_m": 0.1,
                "capabilities": {"grabber": {"kind": "actuating", "time": 1.0, "cost": 1.0}},
            }
        )
    )
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

