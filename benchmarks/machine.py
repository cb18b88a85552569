"""How fast this machine is right now, and a way to make it slower on purpose.

The same 2-core virtual machine has run on hosts of different speed (an AMD
EPYC one ran the throughput benchmark's IaaS at 3.3 ms of CPU per request, an
Intel Xeon one at 5.3 ms, the same code), so results say how fast their
machine was: a fixed workload timed before and after, and the CPU time the
host took for itself meanwhile. ``half_of_each_core`` runs a busy loop on each
core, to see how a result holds on a machine half as fast.
"""

from __future__ import annotations

import contextlib
import json
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Iterator


def reference_ms(repeats: int = 7) -> float:
    """Median milliseconds of a fixed pure-Python workload (JSON, dicts, sorting: an IaaS's mix)."""
    record = {"id": "r-0001", "state": "selecting", "robots": list(range(40)),
              "location": [812.5, 1203.25], "history": [{"at": 1.5, "state": "received"}] * 8}
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for i in range(2_000):
            copy = json.loads(json.dumps(record))
            copy["robots"].sort(key=lambda r: (r * 7919 + i) % 1000)
            _ = {f"{k}-{i}": v for k, v in copy.items()}
        times.append((time.perf_counter() - start) * 1000)
    return statistics.median(times)


def steal_ticks() -> tuple[int, int] | None:
    """(stolen, total) CPU ticks of this machine so far (Linux /proc/stat), or None."""
    try:
        with open("/proc/stat") as stat:
            fields = [int(x) for x in stat.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    return (fields[7] if len(fields) > 7 else 0), sum(fields)


def stolen(before: tuple[int, int] | None) -> str:
    """The share of CPU time the host took since ``before`` (from ``steal_ticks``), as text."""
    after = steal_ticks()
    if before is None or after is None or after[1] <= before[1]:
        return "n/a"
    return f"{100 * (after[0] - before[0]) / (after[1] - before[1]):.1f}%"


@contextlib.contextmanager
def half_of_each_core() -> Iterator[None]:
    """A busy loop pinned to each core, at the same priority, while the block runs.

    The scheduler shares each core between its loop and whatever else runs
    there, so the rest gets about half of it: the reference workload takes
    about twice as long (measured: 60 ms against 30). Without CPU affinity
    (not Linux), nothing is started.
    """
    if not hasattr(os, "sched_setaffinity"):
        yield
        return
    loops = [
        subprocess.Popen([sys.executable, "-c",
                          f"import os\nos.sched_setaffinity(0, {{{core}}})\nwhile True: pass"])
        for core in sorted(os.sched_getaffinity(0))
    ]
    try:
        time.sleep(0.2)
        yield
    finally:
        for loop in loops:
            loop.kill()
        for loop in loops:
            loop.wait(5)
