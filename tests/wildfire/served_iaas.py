"""A ``FakeIaas`` served over real HTTP on loopback, with its missions' event streams.

The wildfire server under test reaches it as it reaches a real IaaS: a socket,
HTTP/1.1, server-sent events (``GET /v1/missions/{id}/events``: ``event:
mission`` with the mission now, then after each change the test makes, until
the mission is final). Every other call is the fake's own answer.
"""

from __future__ import annotations

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import httpx
from fake_iaas import KEY, FakeIaas
from fake_missions import FINAL

from loopback_ports import free_port


class ServedIaas:
    def __init__(self, fake: FakeIaas) -> None:
        self.fake = fake
        self.port = free_port()
        self.streams = 0  # event streams open now
        self.server = ThreadingHTTPServer(("127.0.0.1", self.port), self._handler())
        self.server.daemon_threads = True
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self) -> ServedIaas:
        self.thread.start()
        return self

    def stop(self) -> None:
        with self.fake.lock:
            self.fake.missions.clear()  # the streams end
            self.fake.lock.notify_all()
        self.server.shutdown()
        self.server.server_close()

    def _handler(self) -> type[BaseHTTPRequestHandler]:
        served = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *_: Any) -> None:
                pass

            def _any(self) -> None:
                length = int(self.headers.get("Content-Length") or 0)
                body = self.rfile.read(length) if length else b""
                path = self.path.split("?")[0]
                if path.startswith("/v1/missions/") and path.endswith("/events"):
                    self._events(path.split("/")[3])
                    return
                request = httpx.Request(self.command, f"{served.fake.url}{self.path}",
                                        headers=dict(self.headers), content=body)
                answer = served.fake(request)
                content = answer.read()
                self.send_response(answer.status_code)
                for name, value in answer.headers.items():
                    if name.lower() not in ("content-length", "transfer-encoding", "connection"):
                        self.send_header(name, value)
                self.send_header("Content-Length", str(len(content)))
                self.end_headers()
                self.wfile.write(content)

            do_GET = do_POST = do_DELETE = _any

            def _events(self, mission_id: str) -> None:
                fake = served.fake
                if self.headers.get("Authorization") != f"Bearer {KEY}":
                    self._json(401, {"detail": "the API key is not valid."})
                    return
                with fake.lock:
                    if mission_id not in fake.missions:
                        self._json(404, {"detail": f"there is no mission {mission_id!r}."})
                        return
                self.send_response(200)
                self.send_header("Content-Type", "text/event-stream")
                self.send_header("Cache-Control", "no-store")
                self.send_header("Connection", "close")
                self.end_headers()
                served.streams += 1
                seen = -1
                try:
                    while True:
                        with fake.lock:
                            fake.lock.wait_for(lambda seen=seen: fake.version != seen
                                               or mission_id not in fake.missions, timeout=30)
                            mission = fake.missions.get(mission_id)
                            if mission is None:
                                return
                            seen = fake.version
                            # What was sent, read under the lock: once the lock is
                            # let go, the test may move the mission on (to final)
                            # before this thread looks again, and that event would
                            # never be sent.
                            data = json.dumps(mission)
                            final = mission["state"] in FINAL
                        self.wfile.write(f"event: mission\ndata: {data}\n\n".encode())
                        self.wfile.flush()
                        if final:
                            return
                except (BrokenPipeError, ConnectionResetError):
                    return
                finally:
                    served.streams -= 1
                    self.close_connection = True

            def _json(self, status: int, body: dict[str, Any]) -> None:
                content = json.dumps(body).encode()
                self.send_response(status)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(content)))
                self.end_headers()
                self.wfile.write(content)

        return Handler
