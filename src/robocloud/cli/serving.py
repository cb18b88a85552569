"""Serving an ASGI app from a command: the socket bound first, the lifespan entered by the command.

``robocloud iaas`` binds its HTTP port before it opens anything else (a port
in use is one sentence at once), enters the app's lifespan itself (an error
while opening is raised to the command, which makes it one sentence, rather
than logged by uvicorn as a traceback), and only then lets uvicorn serve,
with ``lifespan="off"``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import socket
import threading
from collections.abc import Iterator

import uvicorn
from fastapi import FastAPI
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

from robocloud.errors import InvalidInput, RoboCloudError

log = logging.getLogger(__name__)


@contextlib.contextmanager
def listen_socket(host: str, port: int, flag: str) -> Iterator[socket.socket]:
    """A TCP socket bound to ``host:port`` (uvicorn listens on it), or a sentence."""
    shown = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    try:
        family, kind, proto, _, address = socket.getaddrinfo(
            host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )[0]
    except socket.gaierror as error:
        raise InvalidInput(
            f"{flag} {shown}: {host!r} is not an address of this machine ({error.strerror}).",
            flag,
        ) from None
    sock = socket.socket(family, kind, proto)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
    except OSError as error:
        sock.close()
        why = (error.strerror or str(error)).lower()
        raise RoboCloudError(f"cannot listen on {shown}: {why}.") from None
    with sock:
        yield sock


def bounded_headers(header_timeout: float) -> type[HttpToolsProtocol]:
    """uvicorn's HTTP protocol (httptools), but a request's headers come within a bound.

    uvicorn times only the silence between two requests of a connection
    (keep-alive, 5 s): a client that opens a connection and sends half a
    request line, or a header a minute (slowloris), held it for ever. Here
    each request's line and headers must be complete ``header_timeout``
    seconds after the connection opened (the first request) or after the
    request's first byte (the next ones on a kept-alive connection); the
    connection is closed otherwise. The body and the answer (an event stream
    lasts) are not timed.
    """

    class BoundedHeaders(HttpToolsProtocol):
        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            self._header_timer: asyncio.TimerHandle | None = None
            super().connection_made(transport)
            self._arm()

        def on_message_begin(self) -> None:
            super().on_message_begin()
            if self._header_timer is None:  # a later request: the first one is already timed
                self._arm()

        def on_headers_complete(self) -> None:
            self._disarm()
            super().on_headers_complete()

        def connection_lost(self, exc: Exception | None) -> None:
            self._disarm()
            super().connection_lost(exc)

        def _arm(self) -> None:
            self._header_timer = self.loop.call_later(header_timeout, self._headers_late)

        def _disarm(self) -> None:
            if self._header_timer is not None:
                self._header_timer.cancel()
                self._header_timer = None

        def _headers_late(self) -> None:
            self._header_timer = None
            if not self.transport.is_closing():
                log.debug(
                    "closed a connection from %s: its request's headers were not complete "
                    "within %g s",
                    self.client,
                    header_timeout,
                )
                self.transport.close()

    return BoundedHeaders


def server_config(app: FastAPI, log_level: str, header_timeout: float) -> uvicorn.Config:
    """uvicorn's configuration for robocloud's servers: headers within ``header_timeout`` s."""
    return uvicorn.Config(
        app,
        log_level=log_level,
        access_log=False,
        lifespan="off",
        http=bounded_headers(header_timeout),
    )


def serve(
    app: FastAPI,
    listener: socket.socket,
    log_level: str,
    header_timeout: float,
    ready: str = "",
) -> None:
    """Enter ``app``'s lifespan, serve on ``listener`` until SIGINT or SIGTERM, close it all.

    ``ready`` is logged (INFO) once the lifespan is open, as the server starts;
    a connection whose request's headers are not complete within
    ``header_timeout`` seconds is closed (``bounded_headers``).
    """
    config = server_config(app, log_level, header_timeout)
    with _sigterm_as_interrupt():
        asyncio.run(_serve(app, config, listener, ready))


async def _serve(app: FastAPI, config: uvicorn.Config, listener: socket.socket, ready: str) -> None:
    async with app.router.lifespan_context(app):
        if ready:
            log.info(ready)
        await _Server(config).serve(sockets=[listener])


class _Server(uvicorn.Server):
    """uvicorn's server, but a signal only stops it: the command closes the rest.

    uvicorn raises the signal again once it has stopped, to end the process as
    the signal would have; here the app's lifespan and the store must still be
    closed after it.
    """

    @contextlib.contextmanager
    def capture_signals(self) -> Iterator[None]:
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        handled = (signal.SIGINT, signal.SIGTERM)
        previous = {sig: signal.signal(sig, self.handle_exit) for sig in handled}
        try:
            yield
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)


@contextlib.contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM while the app opens or closes acts as Ctrl-C: what is open is closed in order."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
