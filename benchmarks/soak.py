"""Soak: thousands of requests, each followed by server-sent events, and the IaaS's memory.

One cloud with 1,000 simulated robots (real processes, robots 200 times faster
than the clock). Sixteen clients each send a request, follow its event stream
until it is final, and cancel it once dispatched, except every tenth request,
which the robots complete. The IaaS's resident memory (VmRSS) is read after
every 500 requests: an IaaS that keeps something per request (a lock, a
listener, an actor, a robot it no longer follows) grows with the count.
"""

from __future__ import annotations

import json
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

import httpx

from benchmarks.report import Column, Goal, SectionReport, Table
from benchmarks.service import TASK, clouds

WORKERS = 16
STEP = 500  # requests between two memory readings
FINAL = {"completed", "rejected", "canceled", "failed"}


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmRSS for process {pid}")


def follow(url: str, key: str, total: int, done: list[str], outcomes: Counter[str],
           lock: threading.Lock, counter: Any) -> None:
    headers = {"Authorization": f"Bearer {key}"}
    with httpx.Client(base_url=url, headers=headers, timeout=60) as client, \
            httpx.Client(base_url=url, headers=headers, timeout=60) as canceller:
        while True:
            with lock:
                i = next(counter, None)
            if i is None:
                return
            answer = client.post("/v1/requests", json={**TASK, "label": f"soak {i}"})
            if answer.status_code != 202:
                with lock:
                    outcomes[f"POST {answer.status_code}"] += 1
                continue
            rid = answer.json()["id"]
            keep = i % 10 == 0
            state = "received"
            with client.stream("GET", f"/v1/requests/{rid}/events") as events:
                for line in events.iter_lines():
                    if not line.startswith("data:"):
                        continue
                    state = json.loads(line[5:])["state"]
                    if state in ("dispatched", "underway") and not keep:
                        canceller.post(f"/v1/requests/{rid}/cancel")
                    if state in FINAL:
                        break
            with lock:
                outcomes[state] += 1
                done.append(rid)


def run(quick: bool, out: Path) -> SectionReport:
    workdir = out / "soak-run"
    workdir.mkdir(parents=True, exist_ok=True)
    total = 1000 if quick else 5000
    step = 100 if quick else STEP
    rows: list[dict[str, Any]] = []
    outcomes: Counter[str] = Counter()
    # Churn: robots also charge (and take other work) on their own, or after a few
    # thousand tasks their batteries would be spent and every request rejected.
    with clouds(workdir, [1000], speedup=200.0, churn=True) as running:
        pid = running.iaas[0].pid
        url, key = running.urls[0], running.key
        done: list[str] = []
        lock = threading.Lock()
        counter = iter(range(total))
        rows.append({"requests": 0, "rss": rss_mb(pid), "seconds": 0.0})
        started = time.perf_counter()
        threads = [
            threading.Thread(target=follow, args=(url, key, total, done, outcomes, lock, counter))
            for _ in range(WORKERS)
        ]
        for t in threads:
            t.start()
        mark = step
        while any(t.is_alive() for t in threads):
            time.sleep(0.2)
            if len(done) >= mark:
                rows.append({"requests": len(done), "rss": rss_mb(pid),
                             "seconds": time.perf_counter() - started})
                mark += step
        for t in threads:
            t.join()
        elapsed = time.perf_counter() - started
        time.sleep(2.0)  # the last actors end, the robots stop
        rows.append({"requests": len(done), "rss": rss_mb(pid), "seconds": elapsed})
    table = Table(
        title=f"IaaS memory over {total:,} requests with event streams (1,000 robots)",
        columns=[Column("requests", "requests finished", "{:,}"),
                 Column("rss", "IaaS RSS MB", "{:.1f}"),
                 Column("seconds", "seconds", "{:.0f}")],
        rows=rows,
    )
    first = next(r["rss"] for r in rows if r["requests"] >= step)
    last = rows[-1]["rss"]
    growth = (last - first) / first * 100
    goals = [Goal(f"RSS after {total:,} requests within 10% of RSS after {step:,}",
                  f"{first:.1f} MB -> {last:.1f} MB ({growth:+.1f}%)", abs(growth) <= 10.0,
                  f"{10.0 - abs(growth):+.1f} points")]
    notes = [
        f"{len(done):,} requests in {elapsed:.0f} s ({len(done) / elapsed:.0f}/s) from "
        f"{WORKERS} clients; outcomes: "
        + ", ".join(f"{k} {v:,}" for k, v in sorted(outcomes.items())) + ".",
        "Each request is canceled once dispatched, except every tenth, which its robots "
        "complete; every request is followed on GET /v1/requests/{id}/events until final.",
    ]
    return SectionReport(name="soak", title="Soak: memory over many requests", rows=rows,
                         tables=[table], notes=notes, goals=goals)
