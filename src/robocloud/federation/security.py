"""Security between clouds on the Zenoh overlay, with Zenoh's own mechanisms.

Three settings, each optional, all off by default (one machine, loopback):

- **TLS with certificates** (``transport/link/tls``): every link is encrypted
  and both ends show a certificate signed by the federation's CA (mutual
  TLS), so only holders of such a certificate join the overlay. A cloud's
  certificate names it: its common name is the cloud's name.
- **Credentials** (``transport/auth/usrpwd``): a session proves a user name
  and password when it joins, and a router with a credentials file (one
  ``user:password`` a line) lets in only the users listed there.
- **Access control** (``access_control``), on a cloud's router when TLS or
  credentials are on: other clouds may ask this cloud's questions (info,
  idle robots, fleet, status), but only the clouds it trusts may send the
  commands for its robots (reserve, confirm, release, dispatch, cancel), and
  nobody outside it may query its robots' command keys directly. With TLS the
  trusted clouds are recognised by their certificate's common name, so the
  ``origin`` a command claims is backed by the link it came on.

``OverlaySecurity.apply`` adds these to a ``zenoh.Config``;
``robocloud.fleet.zenoh_session`` calls it (``open_router(..., security=)``,
``open_client(..., security=)``) and opens ``tcp/`` endpoints as ``tls/``.
``add_arguments`` and ``from_arguments`` are the flags of ``robocloud iaas``
and ``robocloud sim`` (``--tls-ca``, ``--tls-cert``, ``--tls-key``,
``--zenoh-user``, ``--zenoh-password-file``, ``--zenoh-credentials``).
See docs/security.md.

Certificates for tests and operators::

    python -m robocloud.federation.security make-certs --out certs cloud-a cloud-b cloud-c
    python -m robocloud.federation.security make-certs --out certs --host iaas-b.example.org cloud-b

The second run reuses ``certs/ca.pem`` and ``certs/ca.key``. It needs the
``openssl`` command.
"""

from __future__ import annotations

import argparse
import ipaddress
import json
import re
import secrets
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from robocloud.errors import InvalidInput, RoboCloudError

if TYPE_CHECKING:  # only for annotations: the command-line parser stays quick to import
    import zenoh

# What a cloud answers anyone on the overlay, and the commands for its robots
# (the queryables of robocloud.federation.overlay.ZenohOverlay).
QUESTIONS = ("info", "idle", "fleet", "status")
COMMANDS = ("reserve", "confirm", "release", "dispatch", "cancel")

# Every message kind of Zenoh's access control except ``query``.
_NOT_QUERIES = (
    "put",
    "delete",
    "declare_subscriber",
    "declare_queryable",
    "reply",
    "liveliness_token",
    "liveliness_query",
    "declare_liveliness_subscriber",
)

_CERT_BEGIN = "-----BEGIN CERTIFICATE-----"
_KEY_END = "PRIVATE KEY-----"
# A common name make-certs accepts, and that the access control can match.
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
_HOSTNAME = re.compile(r"[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?(\.[A-Za-z0-9-]{1,63})*")
DEFAULT_HOSTS = ("localhost", "127.0.0.1", "::1")


@dataclass(frozen=True)
class OverlaySecurity:
    """TLS files, credentials and (for a cloud's router) whom to trust with commands.

    ``ca`` alone: TLS that checks the router's certificate (a client of a
    router that does not ask for one). ``ca`` with ``cert`` and ``key``:
    mutual TLS, what the IaaS routers use and require of everyone joining.
    ``user`` and ``password``: the credentials this session shows.
    ``credentials``: the file of the users a router lets in.
    ``cloud`` and ``trusted`` (set by ``for_cloud``): the access control.
    """

    ca: Path | None = None
    cert: Path | None = None
    key: Path | None = None
    user: str | None = None
    password: str | None = field(default=None, repr=False)
    credentials: Path | None = None
    cloud: str | None = None
    trusted: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for name in ("ca", "cert", "key", "credentials"):
            value = getattr(self, name)
            if isinstance(value, str):
                object.__setattr__(self, name, Path(value))
        object.__setattr__(self, "trusted", tuple(self.trusted))
        if (self.cert is None) != (self.key is None):
            raise InvalidInput(
                "a TLS certificate and its private key go together: give both or neither "
                "(--tls-cert, --tls-key).",
                field="tls",
            )
        if self.cert is not None and self.ca is None:
            raise InvalidInput(
                "a TLS certificate needs the CA that signed the other clouds' certificates "
                "(--tls-ca).",
                field="tls",
            )
        _check_pem(self.ca, "CA certificate", _CERT_BEGIN)
        _check_pem(self.cert, "certificate", _CERT_BEGIN)
        _check_pem(self.key, "private key", _KEY_END)
        if (self.user is None) != (self.password is None):
            raise InvalidInput(
                "a Zenoh user and password go together: give both or neither.", field="user"
            )
        if self.user is not None:
            _check_user(self.user, "the Zenoh user")
        if self.password is not None and (not self.password or "\n" in self.password):
            raise InvalidInput("the Zenoh password must be one non-empty line.", field="password")
        if self.credentials is not None:
            read_credentials(self.credentials)
        if self.cloud is not None:
            _check_user(self.cloud, "the cloud name")
            for name in self.trusted:
                _check_user(name, "a trusted cloud's name")

    @classmethod
    def from_options(
        cls,
        ca: str | Path | None = None,
        cert: str | Path | None = None,
        key: str | Path | None = None,
        user: str | None = None,
        password_file: str | Path | None = None,
        credentials: str | Path | None = None,
    ) -> OverlaySecurity | None:
        """The security the command-line options ask for; None when they ask for none.

        The password is read from a file (its first line), never from the
        command line, where other users of the machine could see it.
        """
        password = None
        if password_file is not None:
            path = Path(password_file)
            try:
                lines = path.read_text(encoding="utf-8").splitlines()
            except FileNotFoundError:
                raise InvalidInput(
                    f"the Zenoh password file {path} does not exist.", field="password"
                ) from None
            except (OSError, UnicodeDecodeError) as error:
                raise InvalidInput(
                    f"cannot read the Zenoh password file {path}: {error}.", field="password"
                ) from error
            password = lines[0] if lines else ""
        if all(v is None for v in (ca, cert, key, user, password, credentials)):
            return None
        return cls(
            ca=Path(ca) if ca is not None else None,
            cert=Path(cert) if cert is not None else None,
            key=Path(key) if key is not None else None,
            user=user,
            password=password,
            credentials=Path(credentials) if credentials is not None else None,
        )

    # -- what it turns on ------------------------------------------------------

    @property
    def tls(self) -> bool:
        """Whether links are TLS (``tcp/`` endpoints are opened as ``tls/``)."""
        return self.ca is not None

    @property
    def mutual_tls(self) -> bool:
        """Whether this side shows a certificate, and requires one of the other side."""
        return self.cert is not None

    @property
    def identifies_peers(self) -> bool:
        """Whether a router knows who is on each link: a certificate or a login."""
        return self.mutual_tls or self.credentials is not None

    def for_cloud(self, cloud: str, trusted: Iterable[str] = ()) -> OverlaySecurity:
        """This security for the router of ``cloud``: with access control for its robots.

        ``trusted`` empty: every cloud that may join may send commands (as
        ``Settings.trusted`` empty means in ``robocloud.iaas``).
        """
        return replace(self, cloud=cloud, trusted=tuple(trusted))

    def apply(self, config: zenoh.Config, mode: str) -> None:
        """Add these settings to ``config`` of a session in ``mode`` (router or client)."""
        if mode == "router" and self.tls and not self.mutual_tls:
            raise InvalidInput(
                "a router with TLS needs its own certificate and key (--tls-cert, --tls-key).",
                field="tls",
            )
        if mode == "router" and self.user is not None and self.credentials is None:
            # Zenoh then asks everyone who connects for a login, with no list
            # to check it against: nobody gets in, not even the robots.
            raise InvalidInput(
                "a router that logs in with a Zenoh user also needs the credentials file of "
                "the users it lets in (--zenoh-credentials).",
                field="credentials",
            )
        for key, value in self.config_entries(mode).items():
            config.insert_json5(key, json.dumps(value))

    def config_entries(self, mode: str) -> dict[str, Any]:
        """The Zenoh configuration keys and values ``apply`` inserts."""
        entries: dict[str, Any] = {}
        tls = "transport/link/tls"
        if self.ca is not None:
            entries[f"{tls}/root_ca_certificate"] = str(self.ca)
            # The other side's certificate must name the host it is reached
            # at (Zenoh's default, made explicit).
            entries[f"{tls}/verify_name_on_connect"] = True
            # A link ends when the other side's certificate expires.
            entries[f"{tls}/close_link_on_expiration"] = True
        if self.cert is not None and self.key is not None:
            for side in ("listen", "connect"):
                entries[f"{tls}/{side}_certificate"] = str(self.cert)
                entries[f"{tls}/{side}_private_key"] = str(self.key)
            entries[f"{tls}/enable_mtls"] = True
        usrpwd = "transport/auth/usrpwd"
        if self.user is not None:
            entries[f"{usrpwd}/user"] = self.user
            entries[f"{usrpwd}/password"] = self.password
        if self.credentials is not None:
            entries[f"{usrpwd}/dictionary_file"] = str(self.credentials)
        if mode == "router" and self.cloud is not None and self.identifies_peers:
            entries["access_control"] = access_control(
                self.cloud, self.trusted, by_certificate=self.mutual_tls
            )
        return entries


def access_control(
    cloud: str, trusted: Sequence[str] = (), by_certificate: bool = True
) -> dict[str, Any]:
    """Zenoh ``access_control`` for the router of ``cloud``.

    Deny by default, then allow:

    - everyone: every message but queries, both ways; queries going out;
      queries coming in for the questions every cloud answers
      (``robocloud/*/info`` ...), the scatter-gather of the federation;
    - the trusted clouds: queries coming in for this cloud's commands, on
      their exact keys. Everyone may send them when ``trusted`` is empty (as
      ``Settings.trusted`` empty means), or when peers are not known by a
      certificate (``by_certificate`` false): a router knows the user name
      only of the peers that connected to it, not of those it connected to;
    - this cloud itself (its own certificate or user, e.g. its operators'
      tools): every query.

    Allow rules and deny by default, never deny rules: Zenoh applies a rule to
    a message whose key the rule's key includes, so a deny rule on
    ``robocloud/<cloud>/dispatch`` would miss a query on ``robocloud/**``.
    Nobody else may query this cloud's robots' command keys: commands reach
    them through this cloud's IaaS, which checks who holds the robot.
    """
    by = "cert_common_names" if by_certificate else "usernames"
    commands = [f"robocloud/{cloud}/{name}" for name in COMMANDS]
    subjects: list[dict[str, Any]] = [{"id": "anyone"}, {"id": "itself", by: [cloud]}]
    policies: list[dict[str, Any]] = [
        {"id": "anyone", "subjects": ["anyone"], "rules": ["messages", "ask", "answer"]},
        {"id": "itself", "subjects": ["itself"], "rules": ["everything"]},
    ]
    if trusted and by_certificate:
        subjects.append({"id": "trusted", by: sorted(set(trusted))})
        policies.append({"id": "trusted", "subjects": ["trusted"], "rules": ["commands"]})
    else:
        policies[0]["rules"].append("commands")
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": [
            {
                "id": "messages",
                "permission": "allow",
                "flows": ["ingress", "egress"],
                "messages": list(_NOT_QUERIES),
                "key_exprs": ["**"],
            },
            {
                "id": "ask",
                "permission": "allow",
                "flows": ["egress"],
                "messages": ["query"],
                "key_exprs": ["**"],
            },
            {
                "id": "answer",
                "permission": "allow",
                "flows": ["ingress"],
                "messages": ["query"],
                "key_exprs": [f"robocloud/*/{name}" for name in QUESTIONS],
            },
            {
                "id": "commands",
                "permission": "allow",
                "flows": ["ingress"],
                "messages": ["query"],
                "key_exprs": commands,
            },
            {
                "id": "everything",
                "permission": "allow",
                "flows": ["ingress"],
                "messages": ["query"],
                "key_exprs": ["**"],
            },
        ],
        "subjects": subjects,
        "policies": policies,
    }


def read_credentials(path: Path) -> dict[str, str]:
    """The ``user:password`` lines of a credentials file, checked as Zenoh reads them."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InvalidInput(
            f"the Zenoh credentials file {path} does not exist.", field="credentials"
        ) from None
    except (OSError, UnicodeDecodeError) as error:
        raise InvalidInput(
            f"cannot read the Zenoh credentials file {path}: {error}.", field="credentials"
        ) from error
    users: dict[str, str] = {}
    for number, line in enumerate(text.splitlines(), 1):
        user, sep, password = line.partition(":")
        if not sep or not user.strip() or not password.strip():
            raise InvalidInput(
                f"line {number} of the Zenoh credentials file {path} is not user:password "
                "(Zenoh allows no blank lines or comments there).",
                field="credentials",
            )
        users[user.strip()] = password.strip()
    if not users:
        raise InvalidInput(
            f"the Zenoh credentials file {path} lists no user:password.", field="credentials"
        )
    return users


def _check_pem(path: Path | None, what: str, marker: str) -> None:
    if path is None:
        return
    try:
        text = path.read_text(encoding="ascii", errors="replace")
    except FileNotFoundError:
        raise InvalidInput(f"the TLS {what} {path} does not exist.", field="tls") from None
    except OSError as error:
        raise InvalidInput(f"cannot read the TLS {what} {path}: {error}.", field="tls") from error
    if marker not in text:
        raise InvalidInput(f"{path} is not a PEM {what} (no {marker} line).", field="tls")


def _check_user(name: str, what: str) -> None:
    if not name or name != name.strip() or any(ch in name for ch in ":\n\r\t "):
        raise InvalidInput(
            f"{what} {name!r} cannot be a Zenoh user or certificate name: it must be "
            "non-empty, without spaces or colons.",
            field="user",
        )


# -- command-line options ----------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser, router: bool) -> None:
    """The security flags of ``robocloud iaas`` (``router``) and ``robocloud sim``."""
    group = parser.add_argument_group("security on the overlay (docs/security.md)")
    group.add_argument(
        "--tls-ca",
        metavar="PEM",
        help="the federation's CA certificate: turns TLS on (tcp/ endpoints become tls/)",
    )
    group.add_argument(
        "--tls-cert",
        metavar="PEM",
        help="this cloud's certificate, whose common name is the cloud's name"
        if router
        else "the robots' certificate, signed by the same CA",
    )
    group.add_argument("--tls-key", metavar="PEM", help="the private key of --tls-cert")
    group.add_argument(
        "--zenoh-user",
        metavar="USER",
        help="the user this session logs in as (with --zenoh-password-file)",
    )
    group.add_argument(
        "--zenoh-password-file",
        metavar="FILE",
        help="a file whose first line is the password of --zenoh-user",
    )
    if router:
        group.add_argument(
            "--zenoh-credentials",
            metavar="FILE",
            help="user:password lines: the only clouds and robots this router lets in",
        )


def from_arguments(args: argparse.Namespace) -> OverlaySecurity | None:
    """The security the flags of ``add_arguments`` ask for; None when they ask for none."""
    return OverlaySecurity.from_options(
        ca=args.tls_ca,
        cert=args.tls_cert,
        key=args.tls_key,
        user=args.zenoh_user,
        password_file=args.zenoh_password_file,
        credentials=getattr(args, "zenoh_credentials", None),
    )


# -- certificates ---------------------------------------------------------------


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
    openssl = shutil.which("openssl")
    if openssl is None:
        raise RoboCloudError("make-certs needs the openssl command, which is not installed.")
    if not names:
        raise InvalidInput("name at least one cloud to make a certificate for.", field="names")
    for name in names:
        if not _NAME.fullmatch(name):
            raise InvalidInput(
                f"{name!r} cannot be a certificate name: use letters, digits, '.', '_' and '-' "
                "(up to 64), starting with a letter or digit.",
                field="names",
            )
    alt_names = [_alt_name(host) for host in hosts]
    if days < 1:
        raise InvalidInput("certificates must be valid for at least one day.", field="days")
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

    def run(*args: str) -> None:
        # umask 077: keys are never readable by others, not even for a moment.
        done = subprocess.run(
            [openssl, *args], capture_output=True, text=True, check=False, umask=0o077
        )
        if done.returncode != 0:
            raise RoboCloudError(f"openssl {args[0]} failed: {done.stderr.strip()}")

    def new_key(path: Path) -> None:
        run("genpkey", "-algorithm", "EC", "-pkeyopt", "ec_paramgen_curve:P-256", "-out", str(path))

    if not ca.cert.exists():
        new_key(ca.key)
        run(
            "req", "-x509", "-new", "-key", str(ca.key), "-sha256", "-days", str(days),
            "-subj", "/CN=robocloud federation CA",
            "-addext", "basicConstraints=critical,CA:TRUE",
            "-addext", "keyUsage=critical,keyCertSign,cRLSign",
            "-out", str(ca.cert),
        )  # fmt: skip
        ca.cert.chmod(0o644)
    issued: dict[str, Issued] = {}
    with tempfile.TemporaryDirectory() as scratch:
        for name in names:
            leaf = Issued(out / f"{name}.pem", out / f"{name}.key")
            request = Path(scratch) / f"{name}.csr"
            extensions = Path(scratch) / f"{name}.ext"
            sans = list(
                dict.fromkeys([*alt_names, *([f"DNS:{name}"] if _is_hostname(name) else [])])
            )
            extensions.write_text(
                "basicConstraints=critical,CA:FALSE\n"
                "keyUsage=critical,digitalSignature\n"
                "extendedKeyUsage=serverAuth,clientAuth\n"
                f"subjectAltName={','.join(sans)}\n",
                encoding="ascii",
            )
            new_key(leaf.key)
            run("req", "-new", "-key", str(leaf.key), "-subj", f"/CN={name}", "-out", str(request))
            run(
                "x509", "-req", "-in", str(request), "-CA", str(ca.cert), "-CAkey", str(ca.key),
                "-set_serial", f"0x{secrets.token_hex(16)}", "-days", str(days), "-sha256",
                "-extfile", str(extensions), "-out", str(leaf.cert),
            )  # fmt: skip
            leaf.cert.chmod(0o644)
            issued[name] = leaf
    return ca, issued


def _alt_name(host: str) -> str:
    try:
        return f"IP:{ipaddress.ip_address(host)}"
    except ValueError:
        pass
    if not _is_hostname(host):
        raise InvalidInput(f"{host!r} is neither an IP address nor a host name.", field="hosts")
    return f"DNS:{host}"


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
        "A cloud's certificate must have its cloud name (--cloud) as NAME.",
    )
    certs.add_argument("names", nargs="+", metavar="NAME", help="cloud names, e.g. cloud-a")
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


if __name__ == "__main__":
    sys.exit(main())
