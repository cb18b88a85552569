"""The other clouds' idle robots for a selection: asked early, asked once."""

from __future__ import annotations

import asyncio
from typing import Any

from federation_testing import clouds

from robocloud.domain import Task
from robocloud.iaas import lifecycle as lc
from robocloud.iaas.actor import RequestActor, Shell
from robocloud.iaas.routes import RobotRoutes
from robocloud.iaas.selector import SelectorSettings, failed

TASK = {
    "location": [0.0, 0.0],
    "actuating": {"grabber": 1},
    "max_robots": 1,
    "max_cost": 10.0,
    "max_time": 10.0,
}


def test_other_clouds_are_asked_while_the_selecting_state_is_written() -> None:
    """The question to the other clouds travels during the store's write, asked once."""
    network, c = clouds(("cloud-a", "cloud-b"), robots=2)
    a = c["cloud-a"]
    record, _ = a.store.create_request("app", TASK)
    asked_before_write: list[bool] = []
    seen: list[Any] = []

    async def in_thread(function: Any, *args: Any) -> Any:
        return await asyncio.to_thread(function, *args)

    async def slow_store(function: Any, *args: Any) -> Any:
        if function == a.store.transition and args[1] == "selecting":
            await asyncio.sleep(0.1)  # a slow disk
            asked_before_write.append(("cloud-a", "cloud-b", "idle") in network.calls)
        return function(*args)

    async def selector(problem: Any, task: Task) -> Any:
        seen.append(problem.ids)
        return failed(len(problem.ids), 0.0, SelectorSettings(), "none chosen (test)")

    shell = Shell(
        store=a.store,
        view=a.view,
        selector=selector,
        rules=lc.Rules(),
        blocking=in_thread,
        store_write=slow_store,
        publish=lambda _: None,
        routes=RobotRoutes(),
    )
    life = lc.Life(record.id, Task.model_validate(TASK))
    asyncio.run(RequestActor(shell, life, record).run(lc.Start()))
    assert asked_before_write == [True]
    assert seen == [("a-0", "a-1", "b-0", "b-1")]
    assert network.calls.count(("cloud-a", "cloud-b", "idle")) == 1
    assert a.store.get(record.id).state == "failed"  # type: ignore[union-attr]
