"""What reading the router's refusals costs: a router's CPU per state with and without the trace.

``robocloud iaas`` with access control turns on Zenoh's access control trace
and reads it back (``robocloud.federation.security.router_refusals``). Zenoh
then writes a line for every message its router checks, allowed ones
included. Here a router with robocloud's access control and mutual TLS runs
in a process of its own, with a subscriber to the robots' states as the
IaaS has; this process puts ``STATES`` robot states of about 500 bytes with
the fleet's certificate, as fast as Zenoh takes them, and the router's
process reports the CPU it used from the first state to the last. Runs with
and without the trace alternate (``RUNS`` each); the table gives medians, and
what the difference costs at 10,000 states a second (10,000 robots at 1 Hz
each sending its own state; a gateway's batch is one message for many).

Run alone: ``python -m benchmarks.router_trace``.
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import zenoh

from benchmarks.report import Column, Goal, SectionReport, Table, render_text
from benchmarks.service import _port
from robocloud.federation.security import OverlaySecurity, make_certs
from robocloud.fleet import keys, open_client

STATES = 20_000
RUNS = 5

ROUTER = r"""
import json, os, sys, threading, time
from pathlib import Path
from robocloud.federation.security import OverlaySecurity
from robocloud.federation.security.router_refusals import watch
from robocloud.fleet import open_router

certs, endpoint, states, traced = Path(sys.argv[1]), sys.argv[2], int(sys.argv[3]), sys.argv[4]
security = OverlaySecurity(
    ca=certs / "ca.pem", cert=certs / "cloud-a.pem", key=certs / "cloud-a.key"
).for_cloud("cloud-a", ["cloud-b"])
if traced == "1":
    watch("cloud-a", security.config_entries("router")["access_control"])
router = open_router([endpoint], security=security)
done = threading.Event()
seen = [0, 0.0]

def heard(sample):
    if seen[0] == 0:
        seen[1] = time.process_time()
    seen[0] += 1
    if seen[0] == states:
        done.set()

subscriber = router.declare_subscriber("robocloud/cloud-a/robots/*/state", heard)
print("ready", flush=True)
done.wait(30)
used = time.process_time() - seen[1]
time.sleep(0.2)  # the trace's last lines read
print(json.dumps({"cpu_s": used, "heard": seen[0]}), flush=True)
subscriber.undeclare()
router.close()
"""


def _one(certs: Path, traced: bool, quick: bool) -> float:
    """CPU seconds of the router's process for the states, with or without the trace."""
    endpoint = f"tcp/127.0.0.1:{_port()}"
    states = STATES // 4 if quick else STATES
    router = subprocess.Popen(
        [sys.executable, "-c", ROUTER, str(certs), endpoint, str(states), "1" if traced else "0"],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    try:
        assert router.stdout is not None
        assert router.stdout.readline().strip() == "ready"
        fleet = OverlaySecurity(
            ca=certs / "ca.pem", cert=certs / "cloud-a-robots.pem", key=certs / "cloud-a-robots.key"
        )
        session = open_client([endpoint], timeout=10.0, security=fleet)
        payload = json.dumps({"id": "a-1", "padding": "x" * 440})
        try:
            for n in range(states):
                # Blocking, not dropped when the router's queue is full: every state is counted.
                session.put(
                    keys.state_key("cloud-a", f"a-{n % 1000}"),
                    payload,
                    congestion_control=zenoh.CongestionControl.BLOCK,
                )
            result = json.loads(router.stdout.readline())
        finally:
            session.close()  # type: ignore[no-untyped-call]
        assert result["heard"] == states, result
        return float(result["cpu_s"]) / states * 1e6  # microseconds a state
    finally:
        router.wait(30)


def measure(quick: bool, workdir: Path) -> SectionReport:
    certs = workdir / "certs"
    make_certs(certs, ["cloud-a", "cloud-a-robots"])
    plain: list[float] = []
    traced: list[float] = []
    for _ in range(1 if quick else RUNS):
        plain.append(_one(certs, False, quick))
        traced.append(_one(certs, True, quick))
    without, with_trace = statistics.median(plain), statistics.median(traced)
    core = (with_trace - without) * 10_000 / 1e6  # CPU seconds a second
    row = {
        "states": STATES // 4 if quick else STATES,
        "runs": len(plain),
        "us_per_state_plain": without,
        "us_per_state_traced": with_trace,
        "ratio": with_trace / without,
        "core_at_10k": core,
    }
    return SectionReport(
        name="router-trace",
        title="The router's CPU per robot state, with the access control's trace read back",
        rows=[row],
        tables=[
            Table(
                title="router CPU per state (median of the runs, alternating)",
                columns=[
                    Column("states", "states", "{:,}"),
                    Column("runs", "runs"),
                    Column("us_per_state_plain", "without trace (us)", "{:.1f}"),
                    Column("us_per_state_traced", "with trace (us)", "{:.1f}"),
                    Column("ratio", "ratio", "{:.2f}x"),
                    Column("core_at_10k", "core at 10,000/s", "{:.3f}"),
                ],
                rows=[row],
            )
        ],
        notes=[
            "One fleet client puts the states as fast as Zenoh takes them; the router has "
            "one subscriber, as the IaaS has. The trace is on only for a router with access "
            "control (mutual TLS or logins)."
        ],
        goals=[
            Goal(
                "the trace costs under a fifth of a core at 10,000 states a second",
                f"{core:.3f} of a core",
                core < 0.2,
                f"{0.2 - core:+.3f}",
            )
        ],
    )


def run(quick: bool, out_dir: Path) -> SectionReport:
    with tempfile.TemporaryDirectory() as tmp:
        return measure(quick, Path(tmp))


if __name__ == "__main__":
    report = run("--quick" in sys.argv, Path("."))
    print(render_text(report))
