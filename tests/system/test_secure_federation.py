"""Two clouds whose overlay runs on mutual TLS, as docs/security.md turns it on.

The flags of ``robocloud iaas`` and ``robocloud sim`` reach Zenoh: the
federation forms and serves a request across both clouds over ``tls/``
links, and a simulator without a certificate of the federation's CA is kept
out.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from processes import Cloud, follow, grabber_task, start_clouds

from robocloud.federation.security import make_certs

NAMES = ("cloud-a", "cloud-b")


def tls_flags(certs: Path, name: str) -> list[str]:
    return [
        "--tls-ca",
        str(certs / "ca.pem"),
        "--tls-cert",
        str(certs / f"{name}.pem"),
        "--tls-key",
        str(certs / f"{name}.key"),
    ]


@pytest.fixture
def secure_federation(tmp_path: Path) -> Iterator[tuple[list[Cloud], Path]]:
    certs = tmp_path / "certs"
    make_certs(certs, [*NAMES, *(f"{n}-robots" for n in NAMES)])
    other = dict(zip(NAMES, reversed(NAMES), strict=True))
    clouds = start_clouds(
        tmp_path,
        NAMES,
        robots=20,
        speedup=50.0,
        iaas_args=lambda name: [*tls_flags(certs, name), "--trust", other[name]],
        sim_args=lambda name: tls_flags(certs, f"{name}-robots"),
    )
    try:
        yield clouds, certs
    finally:
        for cloud in clouds:
            cloud.stop()


def test_a_request_is_served_across_clouds_over_tls(
    secure_federation: tuple[list[Cloud], Path],
) -> None:
    clouds, _ = secure_federation
    with clouds[0].client() as client:
        task, homes = grabber_task(client)
        assert homes == set(NAMES)
        rid = client.post("/v1/requests", json=task).json()["id"]
        done = follow(
            client, rid, lambda r: r["state"] in ("completed", "failed", "rejected"), 90, "done"
        )
        assert done["state"] == "completed", done
        assert {a["cloud"] for a in done["coalition"]} == set(NAMES)


def test_a_simulator_without_a_certificate_is_kept_out(
    secure_federation: tuple[list[Cloud], Path],
) -> None:
    clouds, certs = secure_federation
    # The CA but no certificate of its own: the router asks for one (mutual TLS).
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "robocloud.cli.main",
            "sim",
            "--cloud",
            "cloud-a",
            "--robots",
            "3",
            "--connect",
            clouds[0].zenoh,
            "--connect-timeout",
            "3",
            "--tls-ca",
            str(certs / "ca.pem"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
        stdin=subprocess.DEVNULL,
    )
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert "cannot open a Zenoh session" in last and "certificate" in last, last
    with clouds[0].client() as client:
        assert len(client.get("/v1/robots").json()) == 20
