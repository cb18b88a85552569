"""What the mutual-TLS system tests share: certificates' flags, a client holding one, a cloud.

The attacks of docs/security.md's table are written as the attacker would:
a Zenoh client at a cloud's router holding a certificate a robot, a gateway
or a member cloud legitimately holds (``session_as``).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import zenoh
from processes import Cloud

from robocloud.federation.security import OverlaySecurity, make_certs
from robocloud.fleet import open_client
from robocloud.fleet.messages import State

KICKER = {"kicker": {"kind": "actuating", "time": 5.0, "cost": 1.0}}


def tls_flags(certs: Path, name: str) -> list[str]:
    """The flags of a command holding ``name``'s certificate (``make-certs`` files)."""
    return [
        *("--tls-ca", str(certs / "ca.pem")),
        *("--tls-cert", str(certs / f"{name}.pem")),
        *("--tls-key", str(certs / f"{name}.key")),
    ]


def session_as(cloud: Cloud, certs: Path, name: str) -> zenoh.Session:
    """A Zenoh client at ``cloud``'s router with the certificate of ``name``."""
    security = OverlaySecurity(
        ca=certs / "ca.pem", cert=certs / f"{name}.pem", key=certs / f"{name}.key"
    )
    return open_client([cloud.zenoh], timeout=5.0, security=security)


def repliers(session: zenoh.Session, key: str, payload: str) -> list[str]:
    """The Zenoh sessions that answer a query on ``key`` (an answer or an error), asked as
    the IaaS asks its robots and other clouds: every queryable (target ALL), every reply
    (no consolidation)."""
    replies = session.get(
        key,
        payload=payload,
        target=zenoh.QueryTarget.ALL,
        consolidation=zenoh.ConsolidationMode.NONE,
        timeout=2.0,
    )
    return [str(r.replier_id.zid) for r in replies if r.replier_id is not None]


def robot_state(
    cloud: str, robot: str, seq: int, position: list[float], battery: float = 90.0
) -> State:
    """An idle robot's state with one kicker, sent now."""
    return State(
        id=robot,
        cloud=cloud,
        kind="tribot",
        position=position,
        speed=1.0,
        battery=battery,
        status="idle",
        travel_cost_per_m=0.01,
        capabilities=KICKER,  # type: ignore[arg-type]
        seq=seq,
        sent_at=time.time(),
    )


def listed(cloud: Cloud) -> dict[str, dict[str, Any]]:
    """The robots ``GET /v1/robots`` lists, by id."""
    with cloud.client() as client:
        return {r["id"]: r for r in client.get("/v1/robots").json()}


@contextlib.contextmanager
def secure_cloud(
    tmp_path: Path, name: str, certificates: Sequence[str], flags: Sequence[str]
) -> Iterator[tuple[Cloud, Path]]:
    """Cloud ``name``'s IaaS alone (no simulator) on mutual TLS, trusting itself, with
    ``flags`` added; certificates for it and for ``certificates``. Robots here send a
    state or two: none turns offline while a test runs (``--offline-after`` 120)."""
    certs = tmp_path / "certs"
    make_certs(certs, [name, *certificates])
    args = [*tls_flags(certs, name), "--trust", name, "--offline-after", "120", *flags]
    cloud = Cloud(name, tmp_path, f"sqlite:///{tmp_path / f'{name}.db'}", 0, 1.0, iaas_args=args)
    try:
        cloud.start_iaas()
        yield cloud, certs
    finally:
        cloud.stop()
