"""Selections in worker processes, each with a hard time limit and a memory cap.

The selection pipeline is pure CPU work; on the event loop's process it would
hold the GIL and stall every other request. Here it runs in a small pool of
worker processes (forked from a fork server, ``worker_context``: they share nothing with
the IaaS's threads):

- the IaaS filters its robots first (Algorithm 2, a vectorised mask over the
  link's columns, ``robocloud.selection.columns``) and sends the candidates'
  ``CoalitionProblem`` only: their ids and a few arrays, which pickle in a
  fraction of a millisecond (Robots or tuples of 8,000 candidates took tens);
- each selection is given a time budget (``select``'s ``budget_s``: a cut
  search returns the best front found so far, said so in the result); a worker
  that has not answered ``grace`` seconds after its budget is killed and
  replaced, and the request fails with that reason;
- each worker's address space is capped (``RLIMIT_AS``): a selection that
  would allocate past it fails with a reason instead of growing the IaaS;
- selections run in parallel, one per worker; when every worker is busy the
  pool starts another, up to ``max_workers``.
"""

from __future__ import annotations

import asyncio
import contextlib
import fcntl
import logging
import multiprocessing
import os
import socket
import struct
import termios
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.reduction import ForkingPickler
from typing import Any

import numpy as np

from robocloud.domain import Task
from robocloud.selection.problem import CoalitionProblem
from robocloud.selection.result import SelectionResult

log = logging.getLogger(__name__)

READY = "ready"
# A message this long or shorter is written to a worker's pipe on the event
# loop: the worker, idle and reading, leaves the socket's buffer (over 200 KB
# on Linux) empty, so the write cannot wait. A longer one is written by a thread.
SEND_AT_ONCE = 64 * 1024


def serve(conn: Connection, memory_mb: int) -> None:
    """A worker process: answer selections until the IaaS closes the pipe.

    Ctrl-C reaches the whole process group; the IaaS alone decides when its
    workers end (it closes the pipe, or kills them), so the worker ignores it.
    """
    import resource
    import signal

    from robocloud.selection.pipeline import select_problem

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    limit = memory_mb * 1024 * 1024
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    with contextlib.suppress(Exception):  # a real selection says what is wrong
        _warm_up(select_problem)
    try:
        conn.send(READY)
        _answer_until_closed(conn, memory_mb, select_problem)
    except (EOFError, OSError):
        return  # the IaaS went away


def _warm_up(select: Any) -> None:
    """One small selection before the first real one: it pays the first calls' costs
    (lazy imports, the solver's set-up), which made a worker's first selection
    several times slower than the next ones."""
    from robocloud.selection.problem import RobotTerms

    task = Task.model_validate(
        {"location": [0.0, 0.0], "sensing": {"s": 1}, "actuating": {"a": 1},
         "max_robots": 2, "max_cost": 100.0, "max_time": 100.0}
    )  # fmt: skip
    uses = np.array([[True, False], [False, True], [True, True], [False, True]])
    terms = RobotTerms(
        time=np.array([3.0, 2.0, 5.0, 1.0]),
        cost=np.array([1.0, 2.0, 2.5, 4.0]),
        uses=uses,
        capabilities=tuple(task.required),
    )
    problem = CoalitionProblem.of_terms(("w-0", "w-1", "w-2", "w-3"), terms, task)
    for optimizer in ("exact", "mopso"):
        select(problem, task, optimizer, budget_s=1.0, ranking=False)


def _answer_until_closed(conn: Connection, memory_mb: int, select: Any) -> None:
    while True:
        message = conn.recv()
        problem, task_json, optimizer, seed, budget_s = message
        try:
            task = Task.model_validate(task_json)
            answer: tuple[str, Any] = (
                "ok",
                # The IaaS keeps no ranking (``failed`` has none either).
                select(problem, task, optimizer, seed=seed, budget_s=budget_s, ranking=False),
            )
        except MemoryError:
            answer = ("error", f"the selection needed more than its {memory_mb} MB of memory")
        except Exception as error:  # one sentence back; the worker goes on
            answer = ("error", f"the selection failed: {error}")
        conn.send(answer)


def worker_context() -> Any:
    """Workers forked from a server process that has imported the pipeline once.

    ``forkserver``: a clean process (not a fork of the IaaS, its threads and
    Zenoh session), started at the first worker, imports numpy and the
    selection pipeline once; each worker is a fork of it. A spawned worker
    imported them itself (benchmarks/results/design-notes.md, forkserver).
    """
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(["robocloud.selection.pipeline"])
    return context


class Worker:
    def __init__(self, context: Any, memory_mb: int) -> None:
        self.conn, child = context.Pipe()
        self.process = context.Process(
            target=serve, args=(child, memory_mb), daemon=True, name="robocloud-selection"
        )
        self.process.start()
        child.close()
        self.ready = False
        self._peer: socket.socket | None = None

    async def call(
        self,
        message: tuple[Any, ...],
        limit: float,
        blocking: Callable[..., Awaitable[Any]],
    ) -> tuple[str, Any] | None:
        """Send a selection and wait up to ``limit`` seconds for its answer (None: no answer).

        On the event loop, without a thread: the message is written at once when
        it fits the pipe's buffer (``blocking`` writes a larger one, which could
        wait for the worker to read it), and the answer is read when the pipe is
        readable: on the loop when all of it has arrived, else by a thread
        within the limit (a worker stopped mid-write never holds the loop). A
        thread for every call cost two hand-offs of the GIL a selection, each
        dearer than the write (benchmarks/results/design-notes.md, worker-pipe).

        A worker that died (killed by the system, say) answers ``("died", why)``.
        """
        try:
            if not self.ready:
                # A cold start imports numpy and the pipeline.
                if not await self._readable(60):
                    return None
                self.conn.recv()
                self.ready = True
            data = bytes(ForkingPickler.dumps(message))
            if len(data) <= SEND_AT_ONCE:
                self.conn.send_bytes(data)
            else:
                await blocking(self.conn.send_bytes, data)
            deadline = time.monotonic() + limit
            if not await self._readable(limit):
                return None
            if self._answer_arrived():
                answer: tuple[str, Any] = self.conn.recv()
            else:
                # Part of it is here: a thread reads the rest, which could wait
                # (a worker stopped in its write, say) while the loop goes on.
                answer = await asyncio.wait_for(
                    blocking(self.conn.recv), max(0.0, deadline - time.monotonic())
                )
        except TimeoutError:
            return None
        except (EOFError, OSError):
            return ("died", "the selection's worker process ended unexpectedly")
        return answer

    def _answer_arrived(self) -> bool:
        """Whether a whole message (or the pipe's end) waits to be read: ``recv`` will not wait.

        A message is its length (4 bytes, big-endian; -1 then 8 bytes for one
        of 2 GB or more) and then its bytes.
        """
        if self._peer is None:  # the pipe's socket, to peek at (a copy of its descriptor)
            self._peer = socket.socket(fileno=os.dup(self.conn.fileno()))
        peer = self._peer
        waiting: int = struct.unpack("i", fcntl.ioctl(peer, termios.FIONREAD, b"\0\0\0\0"))[0]
        if waiting == 0:
            return True  # readable with nothing to read: the worker's end is closed
        if waiting < 4:
            return False
        (size,) = struct.unpack("!i", peer.recv(4, socket.MSG_PEEK))
        return bool(size >= 0 and waiting >= 4 + size)

    async def _readable(self, limit: float) -> bool:
        """Whether the pipe has something to read (an answer, or its end) within ``limit`` s."""
        loop = asyncio.get_running_loop()
        ready = loop.create_future()
        fd = self.conn.fileno()
        loop.add_reader(fd, _wake, ready)
        try:
            await asyncio.wait_for(ready, limit)
        except TimeoutError:
            return False
        finally:
            loop.remove_reader(fd)
        return True

    def kill(self) -> None:
        with contextlib.suppress(Exception):
            self.process.kill()
            self.process.join(5)
        self._close_pipe()

    def _close_pipe(self) -> None:
        if self._peer is not None:
            self._peer.close()
        self.conn.close()

    def close(self) -> None:
        self._close_pipe()  # the worker sees EOF and ends
        self.process.join(2)
        if self.process.is_alive():
            self.kill()


def _wake(ready: asyncio.Future[None]) -> None:
    if not ready.done():
        ready.set_result(None)


@dataclass
class SelectorSettings:
    optimizer: str = "auto"
    seed: int = 0
    budget_s: float = 2.0  # what select may spend; its search stops there
    grace: float = 1.0  # past the budget, the worker is killed
    workers: int = 2  # kept ready
    max_workers: int = 4  # at most, when every worker is busy
    memory_mb: int = 1024  # each worker's address space


class SelectionPool:
    """A ``Selector`` (``robocloud.iaas.actor``): ``await pool(robots, task)``."""

    def __init__(
        self,
        settings: SelectorSettings,
        blocking: Callable[..., Awaitable[Any]],
    ) -> None:
        self.settings = settings
        self._blocking = blocking
        self._context = worker_context()
        self._idle: asyncio.Queue[Worker] = asyncio.Queue()
        self._workers: set[Worker] = set()
        self.killed = 0  # workers killed past their limit, for the logs and tests

    def start(self) -> None:
        for _ in range(self.settings.workers):
            self._idle.put_nowait(self._spawn())

    def _spawn(self) -> Worker:
        worker = Worker(self._context, self.settings.memory_mb)
        self._workers.add(worker)
        return worker

    async def _checkout(self) -> Worker:
        if self._idle.empty() and len(self._workers) < self.settings.max_workers:
            return self._spawn()
        return await self._idle.get()

    async def __call__(self, problem: CoalitionProblem, task: Task) -> SelectionResult:
        settings = self.settings
        started = time.perf_counter()
        candidates = problem.ids
        message = (
            problem,
            task.model_dump(mode="json"),
            settings.optimizer,
            settings.seed,
            settings.budget_s,
        )
        worker = await self._checkout()
        answer = None
        try:
            answer = await worker.call(message, settings.budget_s + settings.grace, self._blocking)
        finally:
            if answer is None or answer[0] == "died":
                self._workers.discard(worker)
                worker.kill()
                self.killed += 1
                if len(self._workers) < settings.workers:
                    self._idle.put_nowait(self._spawn())
            else:
                self._idle.put_nowait(worker)
        elapsed = (time.perf_counter() - started) * 1000
        if answer is None:
            log.warning(
                "a selection over %d candidates ran past its limit; its worker was stopped",
                len(candidates),
            )
            return failed(
                len(candidates),
                elapsed,
                settings,
                f"the selection ran past its time limit of "
                f"{settings.budget_s + settings.grace:g} s and was stopped",
            )
        kind, value = answer
        if kind == "ok":
            assert isinstance(value, SelectionResult)
            return value
        return failed(len(candidates), elapsed, settings, str(value))

    def close(self) -> None:
        for worker in list(self._workers):
            worker.close()
        self._workers.clear()


def failed(
    candidates: int, elapsed_ms: float, settings: SelectorSettings, reason: str
) -> SelectionResult:
    """A selection that did not finish: nothing chosen, not complete, and why."""
    return SelectionResult(
        candidates=candidates,
        ranking=(),
        pareto=(),
        chosen=None,
        reason=reason,
        optimizer="mopso" if settings.optimizer == "mopso" else "exact",
        elapsed_ms=elapsed_ms,
        complete=False,
    )
