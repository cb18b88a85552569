"""Tasks a part of the IaaS owns (structured concurrency): kept until they end,
awaited when the part stops, their errors logged (``spawn_owned``)."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Coroutine
from typing import Any


def spawn_owned(
    tasks: set[asyncio.Task[Any]],
    work: Coroutine[Any, Any, Any],
    what: str,
    log: logging.Logger,
) -> asyncio.Task[Any]:
    """Run ``work`` as a task kept in ``tasks`` until it ends; an error is logged as
    "``what`` failed". The owner cancels and awaits ``tasks`` when it stops."""
    task = asyncio.ensure_future(work)
    tasks.add(task)

    def done(finished: asyncio.Task[Any]) -> None:
        tasks.discard(finished)
        if not finished.cancelled() and finished.exception() is not None:
            log.error("%s failed", what, exc_info=finished.exception())

    task.add_done_callback(done)
    return task
