"""PostgreSQL unreachable for 7 s under load: 503s meanwhile, then no request lost or stuck.

A request's store write that fails as the outage begins is tried again after
pauses that double from 0.2 s up to 5 s (``robocloud.iaas.actor``): 0.2, 0.6,
1.4, 3.0 and 6.2 s into the outage, then 11.2 s, 4.2 s after its end. The
test follows every accepted request to its end, so that late try is awaited.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import httpx
import pytest
from processes import HEADERS, Cloud, wait_until
from sqlalchemy.engine import make_url
from tcp_proxy import TcpProxy

pytestmark = pytest.mark.slow

TASK: dict[str, Any] = {
    "location": [1000.0, 1000.0],
    "actuating": {"grabber": 1},
    "max_robots": 2,
    "max_cost": 1000.0,
    "max_time": 3000.0,
}
FINAL = {"completed", "failed", "rejected", "canceled"}


def test_a_store_outage_answers_503_and_loses_nothing(tmp_path: Path, postgres_url: str) -> None:
    url = make_url(postgres_url)
    proxy = TcpProxy((url.host or "127.0.0.1", url.port or 5432))
    through = url.set(host="127.0.0.1", port=proxy.port).render_as_string(hide_password=False)
    cloud = Cloud("cloud-a", tmp_path, through, robots=30, speedup=200.0)
    answers: list[tuple[float, int, str | None]] = []  # (when, status, request id)
    stop = threading.Event()

    def load() -> None:
        with httpx.Client(base_url=cloud.url, headers=HEADERS, timeout=15) as client:
            i = 0
            while not stop.is_set():
                i += 1
                try:
                    answer = client.post("/v1/requests", json={**TASK, "label": f"r{i}"})
                except httpx.TransportError:
                    answers.append((time.monotonic(), 0, None))
                    continue
                rid = answer.json().get("id") if answer.status_code == 202 else None
                if answer.status_code == 503:
                    assert int(answer.headers["retry-after"]) >= 1
                answers.append((time.monotonic(), answer.status_code, rid))
                time.sleep(0.25)

    try:
        cloud.start()
        sender = threading.Thread(target=load)
        sender.start()
        time.sleep(2)
        cut_at = time.monotonic()
        proxy.cut()
        time.sleep(7)
        proxy.restore()
        back_at = time.monotonic()
        time.sleep(3)
        stop.set()
        sender.join(30)

        statuses = {status for _, status, _ in answers}
        assert statuses <= {202, 503}, statuses
        during = [s for at, s, _ in answers if cut_at + 1 < at < back_at]
        assert 503 in during, during
        after = [s for at, s, _ in answers if at > back_at + 2]
        assert after and all(s == 202 for s in after), after
        accepted = [rid for _, status, rid in answers if status == 202 and rid]
        before = {rid for at, status, rid in answers if status == 202 and at < cut_at}
        later = {rid for at, status, rid in answers if status == 202 and at > back_at}
        assert before and later

        with cloud.client() as client:

            def all_final() -> list[dict[str, Any]] | None:
                got = [client.get(f"/v1/requests/{rid}").json() for rid in accepted]
                return got if all(r.get("state") in FINAL for r in got) else None

            requests = wait_until(all_final, 90, "every accepted request to end")
        for request in requests:
            if request["state"] in ("failed", "rejected"):
                assert request["reason"], request
        completed = {r["id"] for r in requests if r["state"] == "completed"}
        assert completed & before, "no request sent before the outage completed"
        assert completed & later, "no request sent after the outage completed"
    finally:
        stop.set()
        cloud.stop()
        proxy.close()
    log = (tmp_path / "cloud-a-iaas.log").read_text()
    assert "Traceback" not in log, log[-4000:]
