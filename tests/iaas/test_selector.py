"""Selections in worker processes: the in-process answer, a hard limit, a worker replaced."""

from __future__ import annotations

import asyncio
import os
import signal
import time
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from multiprocessing.reduction import ForkingPickler
from typing import Any

import pytest

from robocloud.domain import Robot, Task
from robocloud.iaas.selector import SEND_AT_ONCE, SelectionPool, SelectorSettings, Worker
from robocloud.iaas.service import most_workers
from robocloud.selection.filtering import filter_robots
from robocloud.selection.pipeline import select
from robocloud.selection.problem import CoalitionProblem
from robocloud.sim.scenario import wildfire_robots, wildfire_task

pytestmark = pytest.mark.slow  # each pool spawns Python processes

ROBOTS = [Robot.model_validate(r) for r in wildfire_robots(1000, 3, 1)]
TASK = Task.model_validate(wildfire_task(1))
PROBLEM = CoalitionProblem.build(filter_robots(ROBOTS, TASK), TASK)


def run(settings: SelectorSettings, work: Callable[[SelectionPool], Awaitable[Any]]) -> Any:
    threads = ThreadPoolExecutor(4)

    async def main() -> Any:
        loop = asyncio.get_running_loop()

        async def blocking(function: Callable[..., Any], *args: Any) -> Any:
            return await loop.run_in_executor(threads, lambda: function(*args))

        pool = SelectionPool(settings, blocking)
        pool.start()
        try:
            return await work(pool)
        finally:
            pool.close()

    try:
        return asyncio.run(main())
    finally:
        threads.shutdown()


def test_a_worker_answers_what_the_pipeline_answers_in_process() -> None:
    async def work(pool: SelectionPool) -> Any:
        return [await pool(PROBLEM, TASK) for _ in range(2)]

    answers = run(SelectorSettings(workers=1), work)
    here = select(ROBOTS, TASK, "auto", seed=0, budget_s=2.0)
    for answer in answers:
        assert answer.chosen == here.chosen
        assert answer.pareto == here.pareto
        assert answer.candidates == here.candidates and answer.complete


def test_a_worker_past_its_limit_is_stopped_and_replaced() -> None:
    async def work(pool: SelectionPool) -> Any:
        first = await pool(PROBLEM, TASK)  # the worker is up and answers
        # Then it is frozen (SIGSTOP), so it cannot answer within any limit,
        # however the machine's threads are scheduled. A millisecond's budget
        # raced the worker's own "budget ran out" answer on a loaded machine.
        (worker,) = pool._workers
        os.kill(worker.process.pid, signal.SIGSTOP)
        pool.settings.budget_s, pool.settings.grace = 0.2, 0.1
        late = await pool(PROBLEM, TASK)
        # The pool goes on with a new worker.
        pool.settings.budget_s, pool.settings.grace = 2.0, 1.0
        again = await pool(PROBLEM, TASK)
        return first, late, again, pool.killed, worker.process.is_alive()

    first, late, again, killed, alive = run(SelectorSettings(workers=1), work)
    assert first.chosen is not None
    assert late.chosen is None and late.complete is False
    assert late.reason == "the selection ran past its time limit of 0.3 s and was stopped"
    assert killed == 1 and not alive
    assert again.chosen is not None and again.complete


def test_a_worker_that_dies_is_replaced() -> None:
    async def work(pool: SelectionPool) -> Any:
        first = await pool(PROBLEM, TASK)
        [worker] = list(pool._workers)
        os.kill(worker.process.pid, signal.SIGKILL)
        worker.process.join(5)
        lost = await pool(PROBLEM, TASK)
        after = await pool(PROBLEM, TASK)
        return first, lost, after

    first, lost, after = run(SelectorSettings(workers=1), work)
    assert first.chosen is not None
    assert lost.chosen is None and lost.complete is False
    assert lost.reason == "the selection's worker process ended unexpectedly"
    assert after.chosen == first.chosen


def test_selections_run_side_by_side() -> None:
    async def work(pool: SelectionPool) -> Any:
        return await asyncio.gather(*(pool(PROBLEM, TASK) for _ in range(4)))

    answers = run(SelectorSettings(workers=2, max_workers=4), work)
    assert all(a.chosen == answers[0].chosen for a in answers)


def test_a_problem_larger_than_the_pipe_write_at_once_is_sent_by_a_thread() -> None:
    robots = [Robot.model_validate(r) for r in wildfire_robots(30_000, 3, 2)]
    problem = CoalitionProblem.build(filter_robots(robots, TASK), TASK)
    message = (problem, TASK.model_dump(mode="json"), "auto", 0, 2.0)
    assert len(ForkingPickler.dumps(message)) > SEND_AT_ONCE  # else this tests nothing

    async def work(pool: SelectionPool) -> Any:
        return await pool(problem, TASK), await pool(PROBLEM, TASK)

    large, small = run(SelectorSettings(workers=1), work)
    here = select(robots, TASK, "auto", seed=0, budget_s=2.0)
    assert large.chosen == here.chosen and large.candidates == here.candidates
    assert small.chosen == select(ROBOTS, TASK, "auto", seed=0, budget_s=2.0).chosen


def test_a_selection_given_up_by_its_request_stops_its_worker_and_the_pool_goes_on() -> None:
    async def work(pool: SelectionPool) -> Any:
        first = await pool(PROBLEM, TASK)
        (worker,) = pool._workers
        os.kill(worker.process.pid, signal.SIGSTOP)  # it cannot answer
        waiting = asyncio.ensure_future(pool(PROBLEM, TASK))
        await asyncio.sleep(0.2)
        waiting.cancel()  # the request was canceled meanwhile
        with pytest.raises(asyncio.CancelledError):
            await waiting
        after = await pool(PROBLEM, TASK)
        return first, after, worker.process.is_alive(), len(pool._workers)

    first, after, alive, workers = run(SelectorSettings(workers=1), work)
    assert not alive and workers == 1
    assert after.chosen == first.chosen


def test_an_answer_cut_off_midway_is_waited_for_off_the_loop_within_the_limit() -> None:
    """A worker that stops in the middle of writing its answer never holds the event loop."""
    import multiprocessing
    import struct

    threads = ThreadPoolExecutor(2)

    async def main() -> tuple[Any, int, float]:
        loop = asyncio.get_running_loop()

        async def blocking(function: Callable[..., Any], *args: Any) -> Any:
            return await loop.run_in_executor(threads, lambda: function(*args))

        worker = Worker.__new__(Worker)  # its pipe only: the test writes the worker's side
        worker.conn, child = multiprocessing.Pipe()
        worker.ready, worker._peer = True, None
        ticks = 0

        async def ticking() -> None:
            nonlocal ticks
            while True:
                await asyncio.sleep(0.01)
                ticks += 1

        ticker = asyncio.ensure_future(ticking())
        started = time.monotonic()
        call = asyncio.ensure_future(worker.call(("a selection",), 0.5, blocking))
        await asyncio.sleep(0.05)
        assert child.recv() == ("a selection",)
        os.write(child.fileno(), struct.pack("!i", 1000) + b"x" * 10)  # 10 of its 1,000 bytes
        answer = await call
        elapsed = time.monotonic() - started
        ticker.cancel()
        child.close()  # the reading thread sees the end and stops
        worker._close_pipe()
        return answer, ticks, elapsed

    try:
        answer, ticks, elapsed = asyncio.run(main())
    finally:
        threads.shutdown()
    assert answer is None  # no whole answer within the limit
    assert 0.5 <= elapsed < 2.0
    assert ticks >= 20  # the loop went on meanwhile (50 ticks of 10 ms if never held)


@pytest.mark.parametrize(
    ("kept", "cores", "most"),
    [(2, 2, 2), (2, 8, 4), (1, 2, 2), (1, 1, 1), (4, 2, 4), (3, 4, 4), (3, 16, 6)],
)
def test_the_selection_pool_grows_to_twice_its_workers_but_not_past_the_cores(
    kept: int, cores: int, most: int
) -> None:
    assert most_workers(kept, cores) == most
