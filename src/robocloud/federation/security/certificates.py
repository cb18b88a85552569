"""Certificates for mutual TLS between clouds: one CA for the federation, one certificate per name.

Made with the ``cryptography`` package (no ``openssl`` command needed)::

    python -m robocloud.federation.security make-certs --out certs cloud-a cloud-b cloud-a-robots
    python -m robocloud.federation.security make-certs --out certs --host iaas-b.example.org cloud-b

The second run reuses ``certs/ca.pem`` and ``certs/ca.key``. A certificate's
common name is its name: a cloud's must be the cloud's name (``--cloud``),
its fleet's ``<cloud>-robots``, one robot's ``<cloud>-robot-<id>``
(``policy.robot_name``), which is how the access control recognises them
(``policy``).
"""

from __future__ import annotations

import argparse
import datetime as dt
import ipaddress
import os
import re
import secrets
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from robocloud.errors import InvalidInput, RoboCloudError

# A common name make-certs accepts, and that the access control can match.
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
_HOSTNAME = re.compile(r"[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?(\.[A-Za-z0-9-]{1,63})*")
DEFAULT_HOSTS = ("localhost", "127.0.0.1", "::1")
CA_NAME = "robocloud federation CA"
# Certificates start a little in the past: clocks of the machines differ.
_BACKDATE = dt.timedelta(minutes=5)


@dataclass(frozen=True)
class Issued:
    """A certificate and its private key, as files."""

    cert: Path
    key: Path


def make_certs(
    out: Path, names: Sequence[str], hosts: Sequence[str] = DEFAULT_HOSTS, days: int = 365
) -> tuple[Issued, dict[str, Issued]]:
    """A CA in ``out`` (made once, then reused) and a certificate for each of ``names``.

    Each certificate has the name as its common name (how the access control
    knows a cloud), and ``hosts`` and the name as its subject alternative
    names: a router reached as ``tls/HOST:PORT`` must have HOST among them.
    Every certificate serves both ends of a link (mutual TLS). Keys are
    ECDSA P-256 in PKCS#8, readable by their owner only.
    """
    if not names:
        raise InvalidInput("name at least one cloud to make a certificate for.", field="names")
    for name in names:
        if not _NAME.fullmatch(name):
            raise InvalidInput(
                f"{name!r} cannot be a certificate name: use letters, digits, '.', '_' and '-' "
                "(up to 64), starting with a letter or digit.",
                field="names",
            )
    if len(set(names)) != len(names):
        raise InvalidInput("each name may be given once.", field="names")
    alt_names = [_alt_name(host) for host in hosts]
    if not 1 <= days <= 3650:
        raise InvalidInput("certificates must be valid for 1 to 3650 days.", field="days")
    out.mkdir(parents=True, exist_ok=True)
    ca = Issued(out / "ca.pem", out / "ca.key")
    if ca.cert.exists() != ca.key.exists():
        raise InvalidInput(
            f"{out} holds one of ca.pem and ca.key without the other: remove it or restore both.",
            field="out",
        )
    for name in names:
        for path in (out / f"{name}.pem", out / f"{name}.key"):
            if path.exists():
                raise InvalidInput(
                    f"{path} exists already: remove it to make a new certificate for {name}.",
                    field="names",
                )
    now = dt.datetime.now(dt.UTC)
    if ca.cert.exists():
        ca_cert, ca_key = _read_ca(ca)
    else:
        ca_key = ec.generate_private_key(ec.SECP256R1())
        subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, CA_NAME)])
        ca_cert = (
            _builder(subject, subject, ca_key.public_key(), now, days)
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(_key_usage(signing_certificates=True), critical=True)
            .add_extension(
                x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()), critical=False
            )
            .sign(ca_key, hashes.SHA256())
        )
        _write_key(ca.key, ca_key)
        _write(ca.cert, ca_cert.public_bytes(serialization.Encoding.PEM), 0o644)
    issued: dict[str, Issued] = {}
    for name in names:
        key = ec.generate_private_key(ec.SECP256R1())
        sans = list(
            dict.fromkeys([*alt_names, *([x509.DNSName(name)] if _is_hostname(name) else [])])
        )
        cert = (
            _builder(
                x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]),
                ca_cert.subject,
                key.public_key(),
                now,
                days,
            )
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(_key_usage(signing_certificates=False), critical=True)
            .add_extension(
                x509.ExtendedKeyUsage(
                    [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
                ),
                critical=False,
            )
            .add_extension(x509.SubjectAlternativeName(sans), critical=False)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), False)
            .add_extension(
                x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), False
            )
            .sign(ca_key, hashes.SHA256())
        )
        leaf = Issued(out / f"{name}.pem", out / f"{name}.key")
        _write_key(leaf.key, key)
        _write(leaf.cert, cert.public_bytes(serialization.Encoding.PEM), 0o644)
        issued[name] = leaf
    return ca, issued


def _builder(
    subject: x509.Name,
    issuer: x509.Name,
    public_key: ec.EllipticCurvePublicKey,
    now: dt.datetime,
    days: int,
) -> x509.CertificateBuilder:
    return (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(issuer)
        .public_key(public_key)
        # 127 random bits: positive, and unpredictable (RFC 5280 allows 20 bytes).
        .serial_number(int.from_bytes(secrets.token_bytes(16), "big") >> 1)
        .not_valid_before(now - _BACKDATE)
        .not_valid_after(now + dt.timedelta(days=days))
    )


def _key_usage(signing_certificates: bool) -> x509.KeyUsage:
    return x509.KeyUsage(
        digital_signature=not signing_certificates,
        content_commitment=False,
        key_encipherment=False,
        data_encipherment=False,
        key_agreement=False,
        key_cert_sign=signing_certificates,
        crl_sign=signing_certificates,
        encipher_only=False,
        decipher_only=False,
    )


def _read_ca(ca: Issued) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    try:
        cert = x509.load_pem_x509_certificate(ca.cert.read_bytes())
        key = serialization.load_pem_private_key(ca.key.read_bytes(), password=None)
    except (OSError, ValueError, TypeError) as error:
        raise InvalidInput(
            f"cannot read the CA in {ca.cert} and {ca.key}: {error}.", field="out"
        ) from error
    if not isinstance(key, ec.EllipticCurvePrivateKey):
        raise InvalidInput(f"{ca.key} is not an ECDSA key, as make-certs makes them.", field="out")
    if cert.public_key().public_numbers() != key.public_key().public_numbers():  # type: ignore[union-attr]
        raise InvalidInput(f"{ca.key} is not the key of {ca.cert}.", field="out")
    return cert, key


def _write_key(path: Path, key: ec.EllipticCurvePrivateKey) -> None:
    pem = key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )
    _write(path, pem, 0o600)


def _write(path: Path, data: bytes, mode: int) -> None:
    """Write a new file with ``mode`` from its creation: a key is never readable by others."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    except FileExistsError:
        raise InvalidInput(
            f"{path} exists already: it is never overwritten.", field="out"
        ) from None
    except OSError as error:
        raise RoboCloudError(f"cannot write {path}: {error.strerror}.") from error
    with os.fdopen(fd, "wb") as file:
        file.write(data)
    os.chmod(path, mode)  # the umask may have taken bits from a certificate's 0o644


def _alt_name(host: str) -> x509.GeneralName:
    try:
        return x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        pass
    if not _is_hostname(host):
        raise InvalidInput(f"{host!r} is neither an IP address nor a host name.", field="hosts")
    return x509.DNSName(host)


def _is_hostname(text: str) -> bool:
    return len(text) <= 253 and _HOSTNAME.fullmatch(text) is not None


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m robocloud.federation.security",
        description="Certificates for the robocloud overlay (mutual TLS between clouds).",
    )
    commands = parser.add_subparsers(dest="command", required=True)
    certs = commands.add_parser(
        "make-certs",
        help="a CA (made once, then reused) and a certificate for each cloud",
        description="Write OUT/ca.pem, OUT/ca.key and OUT/NAME.pem, OUT/NAME.key for each NAME. "
        "The name says what the holder is to the routers' access control: a cloud's IaaS "
        "is its cloud name (--cloud), a cloud's fleet (robots, simulators, gateways) is "
        "CLOUD-robots, one robot speaking only for itself is CLOUD-robot-ID (with the IaaS's "
        "--robot-ids); any other name may only listen and ask the clouds' questions.",
    )
    certs.add_argument(
        "names",
        nargs="+",
        metavar="NAME",
        help="e.g. cloud-a (an IaaS), cloud-a-robots (its fleet), cloud-a-robot-a-0001 (one robot)",
    )
    certs.add_argument("--out", required=True, type=Path, metavar="DIR")
    certs.add_argument(
        "--host",
        action="append",
        default=None,
        metavar="HOST",
        help="a host name or IP address the routers are reached at, repeatable "
        f"(default {', '.join(DEFAULT_HOSTS)})",
    )
    certs.add_argument("--days", type=int, default=365, help="validity (default 365)")
    args = parser.parse_args(argv)
    try:
        ca, issued = make_certs(args.out, args.names, args.host or DEFAULT_HOSTS, args.days)
    except RoboCloudError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(f"CA: {ca.cert} (keep {ca.key} offline: it signs new members)")
    for name, leaf in issued.items():
        print(f"{name}: {leaf.cert} {leaf.key}")
    return 0
