"""The parent's side of the child process that runs CP-SAT (``robocloud.planning.child``).

Why a child: see ``solve.py``. The parent writes a pickled request (the
problem, the time limit, the seed, the method and the wall-clock time the
limit counts from) to the child's stdin; the child writes the pickled
:class:`~robocloud.planning.plan.Plan` to stdout. Both ends are this
package, on a pipe nobody else holds.
"""

from __future__ import annotations

import pickle
import subprocess
import sys
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

from robocloud.errors import RoboCloudError

if TYPE_CHECKING:
    from robocloud.planning.plan import Method, Plan
    from robocloud.planning.problem import Problem

# How long past its time limit the child may take (its start, building the
# model, writing the plan) before it is stopped.
GRACE_S = 60.0


def run_worker(problem: Problem, time_limit: float, seed: int, method: Method | None) -> Plan:
    [plan] = run_batch([problem], time_limit, seed, method)
    return plan


def run_batch(
    problems: Sequence[Problem], time_limit: float, seed: int, method: Method | None
) -> list[Plan]:
    """Each problem planned in turn, each within ``time_limit``, in one child.

    The child's start is counted in the first problem's limit only."""
    request = pickle.dumps((list(problems), time_limit, seed, method, time.time()))
    try:
        done = subprocess.run(
            [sys.executable, "-m", "robocloud.planning.child"],
            input=request,
            capture_output=True,
            timeout=time_limit * len(problems) + GRACE_S,
            check=False,
        )
    except subprocess.TimeoutExpired:
        raise RoboCloudError(
            f"the planner did not answer within {time_limit * len(problems) + GRACE_S:g} s "
            "and was stopped."
        ) from None
    if done.returncode != 0:
        last = (done.stderr.decode(errors="replace").strip().splitlines() or ["no message"])[-1]
        raise RoboCloudError(f"the planner stopped with exit code {done.returncode}: {last}")
    plans: list[Plan] = pickle.loads(done.stdout)  # our own child, on our own pipe
    return plans
