"""The running service: POST-to-dispatched latency, GET latency under load, federation gather.

Real processes on loopback, as ``make run`` starts them: one cloud with 1,000
simulated robots, then three clouds with 1,000 robots between them. Robots run
at the clock's speed (speedup 1) so no task finishes during a measurement;
each request is canceled once dispatched, which gives its robots back.

- POST-to-dispatched: the client's time from sending the POST until the
  server-sent events stream says ``dispatched`` (the request's first state
  that is not ``received``/``selecting``), and the server's own time between
  the ``received`` and ``dispatched`` entries of the history.
- GET latency: ``GET /v1/requests/{id}`` sent open-loop at 200 a second for a
  fixed time by a pool of keep-alive clients.
- Gather: the federation view's scatter-gather query (``robocloud/*/idle``
  with a task filter), sent from a Zenoh client of cloud-a's router.
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import socket
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from benchmarks.report import Column, Goal, SectionReport, Table

TASK: dict[str, Any] = {
    "location": [1000.0, 1000.0], "sensing": {"sound": 1}, "actuating": {"grabber": 1},
    "max_robots": 3, "max_cost": 2000.0, "max_time": 5000.0, "min_battery": 20.0,
    "priority": "time",
}


def _port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
    return port


@dataclass
class Running:
    """Clouds started by ``clouds``: their APIs, Zenoh endpoints, API key and IaaS processes."""

    urls: list[str]
    endpoints: list[str]
    key: str
    iaas: list[subprocess.Popen[bytes]]


def terminate_all(processes: list[subprocess.Popen[bytes]], wait: float = 10.0) -> None:
    """SIGTERM to every process, then wait for each; a process still there is killed."""
    for p in processes:
        p.terminate()
    for p in processes:
        try:
            p.wait(wait)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(5)


@contextlib.contextmanager
def clouds(
    workdir: Path,
    counts: list[int],
    speedup: float = 1.0,
    churn: bool = False,
    recharge_below: float | None = None,
    iaas_args: Sequence[str] = (),
) -> Iterator[Running]:
    """Start len(counts) clouds (IaaS + simulator), robots ``speedup`` times the clock.

    ``recharge_below``: idle robots below that battery charge (the simulator's
    ``--recharge-below``), so a long stream of tasks does not run the fleet dry.
    ``iaas_args``: more flags for each ``robocloud iaas``.
    """
    recharge = [] if recharge_below is None else ["--recharge-below", str(recharge_below)]
    key = secrets.token_urlsafe(12)
    env = {**os.environ, "ROBOCLOUD_API_KEYS": f"bench={key}"}
    python = [sys.executable, "-m", "robocloud.cli.main"]
    processes: list[subprocess.Popen[bytes]] = []
    urls: list[str] = []
    endpoints: list[str] = []
    iaas: list[subprocess.Popen[bytes]] = []
    try:
        for i, n in enumerate(counts):
            name = f"cloud-{'abc'[i]}"
            http, zenoh_port = _port(), _port()
            endpoint = f"tcp/127.0.0.1:{zenoh_port}"
            log = open(workdir / f"{name}-iaas.log", "ab")  # noqa: SIM115
            processes.append(subprocess.Popen(
                [*python, "iaas", "--cloud", name, "--listen", f"127.0.0.1:{http}",
                 "--zenoh", endpoint, "--store", f"sqlite:///{workdir / f'{name}.db'}",
                 "--time-scale", str(speedup), "--log-level", "warning",
                 *[a for e in endpoints for a in ("--peer", e)], *iaas_args],
                stdout=log, stderr=subprocess.STDOUT, env=env))
            iaas.append(processes[-1])
            urls.append(f"http://127.0.0.1:{http}")
            endpoints.append(endpoint)
            _wait(lambda u=urls[-1]: httpx.get(f"{u}/healthz", timeout=1).status_code == 200, 30)
            log = open(workdir / f"{name}-sim.log", "ab")  # noqa: SIM115
            processes.append(subprocess.Popen(
                [*python, "sim", "--cloud", name, "--robots", str(n), "--connect", endpoint,
                 "--seed", str(i), "--speedup", str(speedup), *([] if churn else ["--no-churn"]),
                 *recharge],
                stdout=log, stderr=subprocess.STDOUT))
        headers = {"Authorization": f"Bearer {key}"}
        for url, n in zip(urls, counts, strict=True):
            _wait(lambda u=url, n=n: len(httpx.get(f"{u}/v1/robots", headers=headers,
                                                   timeout=5).json()) >= n, 60)
        if len(urls) > 1:
            _wait(lambda: len(httpx.get(f"{urls[0]}/v1/clouds", headers=headers,
                                        timeout=5).json()) == len(urls), 30)
        yield Running(urls, endpoints, key, iaas)
    finally:
        terminate_all(processes)


def _wait(predicate: Any, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with contextlib.suppress(httpx.TransportError):
            if predicate():
                return
        time.sleep(0.1)
    raise RuntimeError("the system did not come up; see the logs in the bench folder")


def timestamp_of(text: str) -> float:
    """An ISO time of the API (``Z`` or an offset) as seconds since the epoch."""
    return datetime.fromisoformat(text.replace("Z", "+00:00")).timestamp()


def measure_dispatch(client: httpx.Client, label: str, into: dict[str, Any]) -> None:
    """One request: POST, follow its events until it is decided, cancel it once dispatched.

    Adds to ``into``: ``sent``; and when dispatched the client's time (``client``,
    ms from the POST), the server's (``server``, received to dispatched in the
    history) and whether a robot came from another cloud than cloud-a (``remote``).
    """
    started = time.perf_counter()
    rid = client.post("/v1/requests", json={**TASK, "label": label}).json()["id"]
    into["sent"] += 1
    state = None
    with client.stream("GET", f"/v1/requests/{rid}/events") as events:
        for line in events.iter_lines():
            if line.startswith("data:"):
                state = json.loads(line[5:])
                if state["state"] not in ("received", "selecting"):
                    break
    elapsed = (time.perf_counter() - started) * 1000
    assert state is not None
    if state["state"] in ("dispatched", "underway"):
        into["client"].append(elapsed)
        at = {h["state"]: timestamp_of(h["at"]) for h in state["history"] if h["kind"] == "state"}
        into["server"].append((at["dispatched"] - at["received"]) * 1000)
        into["remote"] += any(a["cloud"] != "cloud-a" for a in state["coalition"])
        client.post(f"/v1/requests/{rid}/cancel")


def post_to_dispatched(
    url: str, key: str, count: int, limit: float | None = None, label: str = "bench"
) -> dict[str, Any]:
    """Up to ``count`` sequential requests, each canceled once dispatched; latencies in ms.

    ``limit``: no new request after that many seconds, so a fleet where a
    request takes seconds still ends.
    """
    into: dict[str, Any] = {"client": [], "server": [], "remote": 0, "sent": 0}
    headers = {"Authorization": f"Bearer {key}"}
    deadline = None if limit is None else time.monotonic() + limit
    with httpx.Client(base_url=url, headers=headers, timeout=30) as client:
        while into["sent"] < count and (deadline is None or time.monotonic() < deadline):
            measure_dispatch(client, f"{label} {into['sent']}", into)
    return into


def get_under_load(url: str, key: str, rate: float, seconds: float,
                   workers: int = 8) -> dict[str, Any]:
    headers = {"Authorization": f"Bearer {key}"}
    with httpx.Client(base_url=url, headers=headers, timeout=30) as client:
        ids = [r["id"] for r in client.get("/v1/requests", params={"limit": 50}).json()["items"]]
    latencies: list[float] = []
    lock = threading.Lock()
    total = int(rate * seconds)
    start = time.perf_counter() + 0.2
    counter = iter(range(total))
    late = 0

    def worker() -> None:
        nonlocal late
        with httpx.Client(base_url=url, headers=headers, timeout=30) as c:
            while True:
                with lock:
                    i = next(counter, None)
                if i is None:
                    return
                due = start + i / rate
                wait = due - time.perf_counter()
                if wait > 0:
                    time.sleep(wait)
                elif wait < -0.05:
                    with lock:
                        late += 1
                t0 = time.perf_counter()
                c.get(f"/v1/requests/{ids[i % len(ids)]}").raise_for_status()
                with lock:
                    latencies.append((time.perf_counter() - t0) * 1000)

    threads = [threading.Thread(target=worker) for _ in range(workers)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    achieved = len(latencies) / (time.perf_counter() - start)
    return {"ms": latencies, "achieved": achieved, "late": late}


def gather_times(endpoint: str, count: int) -> list[float]:
    import zenoh

    from robocloud.fleet import open_client

    session = open_client([endpoint], timeout=5)
    payload = json.dumps({"origin": "bench", "min_battery": TASK["min_battery"],
                          "capabilities": ["sound", "grabber"]})
    times = []
    try:
        time.sleep(1)
        for _ in range(count):
            t0 = time.perf_counter()
            replies = list(session.get("robocloud/*/idle", payload=payload,
                                       target=zenoh.QueryTarget.ALL,
                                       consolidation=zenoh.ConsolidationMode.NONE,
                                       timeout=1.0))
            times.append((time.perf_counter() - t0) * 1000)
            assert len([r for r in replies if r.ok is not None]) == 3
    finally:
        session.close()
    return times


def _median(xs: list[float]) -> float:
    return float(statistics.median(xs)) if xs else float("nan")


def _p99(xs: list[float]) -> float:
    return float(np.percentile(xs, 99)) if xs else float("nan")


def run(quick: bool, out: Path) -> SectionReport:
    workdir = out / "service-run"
    workdir.mkdir(parents=True, exist_ok=True)
    posts = 30 if quick else 100
    load_seconds = 3.0 if quick else 10.0
    rows: list[dict[str, Any]] = []
    with clouds(workdir, [1000]) as running:
        one = post_to_dispatched(running.urls[0], running.key, posts)
        load = get_under_load(running.urls[0], running.key, 200.0, load_seconds)
    rows.append({"setup": "1 cloud, 1,000 robots", "what": "POST to dispatched (client)",
                 "n": len(one["client"]), "median": _median(one["client"]),
                 "p99": _p99(one["client"])})
    rows.append({"setup": "1 cloud, 1,000 robots", "what": "received to dispatched (server)",
                 "n": len(one["server"]), "median": _median(one["server"]),
                 "p99": _p99(one["server"])})
    rows.append({"setup": "1 cloud, 1,000 robots",
                 "what": f"GET state at 200/s ({load['achieved']:.0f}/s achieved)",
                 "n": len(load["ms"]), "median": _median(load["ms"]), "p99": _p99(load["ms"])})
    with clouds(workdir, [334, 333, 333]) as running:
        gathers = gather_times(running.endpoints[0], 50 if quick else 200)
        fed = post_to_dispatched(running.urls[0], running.key, posts)
    rows.append({"setup": "3 clouds, 1,000 robots", "what": "gather idle robots (3 clouds)",
                 "n": len(gathers), "median": _median(gathers), "p99": _p99(gathers)})
    rows.append({"setup": "3 clouds, 1,000 robots",
                 "what": f"POST to dispatched (client; {fed['remote']} of "
                         f"{len(fed['client'])} coalitions use other clouds)",
                 "n": len(fed["client"]), "median": _median(fed["client"]),
                 "p99": _p99(fed["client"])})
    rows.append({"setup": "3 clouds, 1,000 robots", "what": "received to dispatched (server)",
                 "n": len(fed["server"]), "median": _median(fed["server"]),
                 "p99": _p99(fed["server"])})
    table = Table(
        title="Service latency (ms), real processes on loopback",
        columns=[Column("setup", "setup"), Column("what", "measured"), Column("n", "n"),
                 Column("median", "median ms", "{:.1f}"), Column("p99", "p99 ms", "{:.1f}")],
        rows=rows,
    )
    median_dispatch = _median(one["client"])
    p99_get = _p99(load["ms"])
    goals = [
        Goal("POST to dispatched < 50 ms median (1 cloud, 1,000 robots)",
             f"{median_dispatch:.1f} ms", median_dispatch < 50,
             f"{50 - median_dispatch:+.1f} ms"),
        Goal("GET state p99 < 10 ms at 200 requests/s", f"{p99_get:.1f} ms", p99_get < 10,
             f"{10 - p99_get:+.1f} ms"),
    ]
    ratio = _median(fed["client"]) / median_dispatch if median_dispatch else float("nan")
    notes = [
        f"Three clouds vs one, POST to dispatched median: {ratio:.2f}x "
        f"({_median(fed['client']):.1f} ms vs {median_dispatch:.1f} ms), same run.",
        f"GET load: {load['late']} of {len(load['ms'])} requests were sent more than 50 ms "
        "late (the load generator shares the 2 cores with the IaaS and the simulator).",
        "Requests and robots: each request needs a grabber and a sound sensor (at most 3 "
        "robots), is canceled once dispatched; robots do not move on their own (--no-churn).",
    ]
    return SectionReport(name="service", title="The running service", rows=rows,
                         tables=[table], notes=notes, goals=goals)
