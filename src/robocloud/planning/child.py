"""The planner's child process (``python -m robocloud.planning.child``), started by ``worker.py``.

It reads the pickled problems on stdin, plans each with ``solve_here`` (OR-Tools
is imported here, never in the IaaS's own process: see ``solve.py``), and
writes the pickled plans on stdout.
"""

from __future__ import annotations

import pickle
import sys
import time

from robocloud.planning.solve import solve_here


def main() -> int:
    problems, time_limit, seed, method, sent = pickle.loads(sys.stdin.buffer.read())
    # The limit counts from the parent's call: take off the child's start.
    started = time.perf_counter() - max(0.0, time.time() - sent)
    plans = []
    for problem in problems:
        plans.append(solve_here(problem, time_limit, seed, method, started=started))
        started = time.perf_counter()
    sys.stdout.buffer.write(pickle.dumps(plans))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
