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
from processes import Cloud, follow, grabber_task, wait_until

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
    clouds: list[Cloud] = []
    for i, name in enumerate(NAMES):
        cloud = Cloud(
            name,
            tmp_path,
            f"sqlite:///{tmp_path / f'{name}.db'}",
            robots=20,
            speedup=50.0,
            seed=i,
            iaas_args=[*tls_flags(certs, name), "--trust", NAMES[1 - i]],
            sim_args=tls_flags(certs, f"{name}-robots"),
        )
        cloud.peers = [c.zenoh for c in clouds]
        clouds.append(cloud)
    try:
        for cloud in clouds:
            cloud.start()
        yield clouds, certs
    finally:
        for cloud in clouds:
            cloud.stop()


def test_a_request_is_served_across_clouds_over_tls(
    secure_federation: tuple[list[Cloud], Path],
) -> None:
    clouds, _ = secure_federation
    with clouds[0].client() as client:
        wait_until(
            lambda: [c["cloud"] for c in client.get("/v1/clouds").json()] == list(NAMES),
            20,
            "both clouds to see each other over TLS",
        )
        task, clouds = grabber_task(client)
        assert clouds == set(NAMES)
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
