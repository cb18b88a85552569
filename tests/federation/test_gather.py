"""The other clouds' idle robots for a selection: asked early, asked once."""

from __future__ import annotations

import asyncio
from typing import Any

from federation_testing import candidates_seen, clouds


def test_other_clouds_are_asked_while_the_selecting_state_is_written() -> None:
    """The question to the other clouds travels during the store's write, asked once."""
    network, c = clouds(("cloud-a", "cloud-b"), robots=2)
    a = c["cloud-a"]
    asked_before_write: list[bool] = []

    async def slow_store(function: Any, *args: Any) -> Any:
        if function == a.store.transition and args[1] == "selecting":
            await asyncio.sleep(0.1)  # a slow disk
            asked_before_write.append(("cloud-a", "cloud-b", "idle") in network.calls)
        return function(*args)

    assert candidates_seen(a, store_write=slow_store) == [("a-0", "a-1", "b-0", "b-1")]
    assert asked_before_write == [True]
    assert network.calls.count(("cloud-a", "cloud-b", "idle")) == 1
    (record,), _ = a.store.list("app")
    assert record.state == "failed"
