"""Opening Zenoh sessions the way robocloud uses them, and waiting for the other side.

An IaaS is a Zenoh router (the thesis's super peer) in its own process;
its robots are Zenoh clients connected to it. Multicast scouting is off, so
a session only talks to the endpoints it is given: nothing leaves the
machine unless an endpoint says so.

Sessions are plain TCP unless a ``SessionSecurity`` is given (the overlay's
is ``robocloud.federation.security.OverlaySecurity``): it adds Zenoh's own
TLS, user-password and access-control settings to the configuration, and
with TLS on, ``tcp/`` endpoints become ``tls/``.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Sequence
from typing import Protocol

import zenoh

from robocloud.errors import InvalidInput

EXAMPLE_ENDPOINT = "tcp/127.0.0.1:7447"
# Link protocols that carry the overlay encrypted when TLS is on (Zenoh's QUIC
# reads the same transport/link/tls settings).
_ENCRYPTED = ("tls/", "quic/")


class SessionSecurity(Protocol):
    """How a session authenticates and encrypts its links.

    Defined here so the fleet layer needs nothing of the federation layer;
    ``robocloud.federation.security.OverlaySecurity`` is the implementation.
    """

    @property
    def tls(self) -> bool:
        """Whether links are TLS: ``tcp/`` endpoints are then opened as ``tls/``."""
        ...

    def apply(self, config: zenoh.Config, mode: str) -> None:
        """Add the security settings to ``config`` for a session of ``mode``."""
        ...


def secure_endpoints(
    endpoints: Sequence[str], security: SessionSecurity | None, field: str
) -> list[str]:
    """``endpoints`` as opened under ``security``: ``tcp/`` becomes ``tls/`` when TLS is on.

    With TLS on, an endpoint of another protocol (``udp/``, ``ws/``, ...)
    would carry the overlay in the clear, so it is refused.
    """
    if security is None or not security.tls:
        return list(endpoints)
    out = []
    for endpoint in endpoints:
        if endpoint.startswith("tcp/"):
            endpoint = "tls/" + endpoint.removeprefix("tcp/")
        if not endpoint.startswith(_ENCRYPTED):
            raise InvalidInput(
                f"{endpoint} would not be encrypted: with TLS on, Zenoh endpoints must be "
                "tcp/ (opened as tls/), tls/ or quic/.",
                field=field,
            )
        out.append(endpoint)
    return out


def _config(
    mode: str,
    listen: Sequence[str],
    connect: Sequence[str],
    security: SessionSecurity | None = None,
) -> zenoh.Config:
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(mode))
    config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    config.insert_json5("connect/endpoints", json.dumps(list(connect)))
    config.insert_json5("scouting/multicast/enabled", "false")
    # A router otherwise waits scouting/delay (500 ms) in open() for scouted
    # peers; with multicast off there are none to wait for.
    config.insert_json5("scouting/delay", "0")
    if security is not None:
        security.apply(config, mode)
    return config


def open_router(
    listen: Sequence[str],
    connect: Sequence[str] = (),
    security: SessionSecurity | None = None,
) -> zenoh.Session:
    """A router session listening on ``listen`` (e.g. ``tcp/127.0.0.1:7447``).

    ``connect`` lists other routers to join (other IaaSs). With ``security``,
    links are authenticated (and encrypted with TLS) as it says.
    """
    if not listen:
        raise InvalidInput("a router needs at least one endpoint to listen on.", field="listen")
    listen = secure_endpoints(listen, security, "listen")
    connect = secure_endpoints(connect, security, "connect")
    config = _build("router", listen, connect, security, field="listen")
    return _open(config, [*listen, *connect], security, field="listen")


def open_client(
    connect: Sequence[str], timeout: float = 0.0, security: SessionSecurity | None = None
) -> zenoh.Session:
    """A client session connected to the router at one of ``connect``.

    With ``timeout`` > 0, keeps trying for that many seconds, so a robot may
    start before its IaaS. With ``security``, the link is authenticated (and
    encrypted with TLS) as it says.
    """
    if not connect:
        raise InvalidInput("a client needs an endpoint to connect to.", field="connect")
    connect = secure_endpoints(connect, security, "connect")
    config = _build("client", (), connect, security, field="connect")
    deadline = time.monotonic() + timeout
    while True:
        try:
            return _open(config, connect, security, field="connect")
        except InvalidInput:
            if time.monotonic() >= deadline:
                raise
            time.sleep(0.2)


def _build(
    mode: str,
    listen: Sequence[str],
    connect: Sequence[str],
    security: SessionSecurity | None,
    field: str,
) -> zenoh.Config:
    try:
        return _config(mode, listen, connect, security)
    except zenoh.ZError as error:  # an endpoint or a setting Zenoh cannot read
        raise _cannot_open([*listen, *connect], error, security, field) from error


def _open(
    config: zenoh.Config,
    endpoints: Sequence[str],
    security: SessionSecurity | None,
    field: str,
) -> zenoh.Session:
    try:
        return zenoh.open(config)
    except zenoh.ZError as error:
        raise _cannot_open(endpoints, error, security, field) from error


def _cannot_open(
    endpoints: Sequence[str],
    error: zenoh.ZError,
    security: SessionSecurity | None,
    field: str,
) -> InvalidInput:
    hint = ""
    if security is not None:
        hint = " (with security on, each side must accept the other's certificate and credentials)"
    return InvalidInput(
        f"cannot open a Zenoh session on {', '.join(endpoints)}: {_reason(error)}{hint}.",
        field=field,
    )


def _reason(error: zenoh.ZError) -> str:
    """Zenoh's sentence without the Rust source locations and debug wrapping around it."""
    text = str(error)
    if 'msg: "' in text:
        text = text.split('msg: "', 1)[1]
    return text.split(" at /", 1)[0].strip().rstrip('".!')


def wait_for_liveliness(session: zenoh.Session, key_expr: str, timeout: float) -> bool:
    """Whether a liveliness token matching ``key_expr`` is seen within ``timeout`` seconds.

    A ``get`` sent before the routes to a queryable are known returns no
    reply at once; a token declared by the other side after its queryables
    tells that it is reachable.
    """
    seen = threading.Event()

    def on_sample(sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            seen.set()

    subscriber = session.liveliness().declare_subscriber(key_expr, on_sample, history=True)
    try:
        return seen.wait(timeout)
    finally:
        subscriber.undeclare()  # type: ignore[no-untyped-call]


def check_endpoints(endpoints: Sequence[str], flag: str) -> None:
    """Each endpoint in Zenoh's form (``tcp/127.0.0.1:7447``), as Zenoh itself reads it."""
    for endpoint in endpoints:
        try:
            zenoh.Config().insert_json5("connect/endpoints", json.dumps([endpoint]))
        except zenoh.ZError:
            raise InvalidInput(
                f"{flag} {endpoint!r} is not a Zenoh endpoint; write PROTOCOL/ADDRESS, "
                f"e.g. {EXAMPLE_ENDPOINT}.",
                flag,
            ) from None
