"""The NXT link: direct commands a second over one link, and the latency of a sensor read.

Measured against the stand-in brick (``robocloud nxt-brick``, its own process)
over loopback TCP with the gateway's own link and codec
(``robocloud.gateways.nxt.transport`` and ``telegrams``), so it measures the
gateway's side and the stand-in, not Bluetooth: a real NXT's Bluetooth adds
tens of milliseconds a round trip (each direction change of its serial link),
which bounds a real brick to a few tens of answered commands a second.

- round trips a second: GETOUTPUTSTATE, one after the other, for ``WINDOW`` s;
- a sensor read: GETINPUTVALUES of the light sensor, one at a time
  (``READS`` of them): the time from sending it to having its value decoded.

Run alone: ``python -m benchmarks.nxt``.
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.report import Column, Goal, SectionReport, Table, render_text
from benchmarks.service import _port
from robocloud.gateways.nxt import telegrams as t
from robocloud.gateways.nxt.transport import LinkDown, SocketLink, connect_tcp

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "nxt" / "thesis-bricks.json"
ROBOT = "nxt-base-1"
WINDOW = 3.0  # seconds of back-to-back round trips
READS = 500


def _connect(port: int, deadline: float) -> SocketLink:
    while True:
        try:
            return connect_tcp("127.0.0.1", port, 1.0)
        except LinkDown:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


def measure(quick: bool, workdir: Path) -> SectionReport:
    port = _port()
    data = json.loads(EXAMPLE.read_text())
    data["robots"] = {ROBOT: {**data["robots"][ROBOT], "reach": {"tcp": f"127.0.0.1:{port}"}}}
    bricks = workdir / "bricks.json"
    bricks.write_text(json.dumps(data))
    brick = subprocess.Popen(
        [sys.executable, "-m", "robocloud.cli.main", "nxt-brick", "--bricks", str(bricks),
         "--robot", ROBOT],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        link = _connect(port, time.monotonic() + 20)
        t.parse_status(link.exchange(t.set_input_mode(2, 0x05, t.PERCENT_MODE)), t.SETINPUTMODE)
        window = 1.0 if quick else WINDOW
        count, started = 0, time.perf_counter()
        while time.perf_counter() - started < window:
            t.parse_output_state(link.exchange(t.get_output_state(1)))
            count += 1
        per_second = count / (time.perf_counter() - started)
        latencies = []
        for _ in range(100 if quick else READS):
            sent = time.perf_counter()
            t.parse_input_values(link.exchange(t.get_input_values(2)))
            latencies.append((time.perf_counter() - sent) * 1000.0)
        link.close()
    finally:
        brick.terminate()
        brick.wait(10)
    latencies.sort()
    row = {
        "round_trips_per_s": per_second,
        "read_p50_ms": statistics.median(latencies),
        "read_p95_ms": latencies[int(0.95 * (len(latencies) - 1))],
        "read_max_ms": latencies[-1],
        "reads": len(latencies),
    }
    table = Table(
        "One link to a stand-in brick over loopback TCP (not Bluetooth)",
        [
            Column("round_trips_per_s", "commands/s (round trips)", "{:.0f}"),
            Column("read_p50_ms", "sensor read p50 ms", "{:.2f}"),
            Column("read_p95_ms", "p95 ms", "{:.2f}"),
            Column("read_max_ms", "max ms", "{:.2f}"),
            Column("reads", "reads"),
        ],
        [row],
    )
    # The gateway polls a moving brick's motors every 20 ms: 2-3 round trips a cycle.
    goal = Goal(
        "the link keeps up with the driver's cycle (3 round trips each 20 ms: 150/s)",
        f"{per_second:.0f} round trips/s",
        per_second >= 150,
        f"{per_second / 150:.0f}x",
    )
    return SectionReport("nxt", "NXT direct commands over one link", [row], [table], goals=[goal])


def run(quick: bool, out: Path) -> SectionReport:
    with tempfile.TemporaryDirectory() as workdir:
        return measure(quick, Path(workdir))


if __name__ == "__main__":
    with tempfile.TemporaryDirectory() as tmp:
        print(render_text(measure(False, Path(tmp))))
