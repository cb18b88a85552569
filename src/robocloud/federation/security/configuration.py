"""The overlay's security settings: TLS files, logins, whom a router trusts, and their flags.

Three settings, each optional, all off by default (one machine, loopback):

- **TLS with certificates** (``transport/link/tls``): every link is encrypted
  and both ends show a certificate signed by the federation's CA (mutual
  TLS), so only holders of such a certificate join the overlay. A cloud's
  certificate names it: its common name is the cloud's name.
- **Credentials** (``transport/auth/usrpwd``): a session proves a user name
  and password when it joins, and a router with a credentials file (one
  ``user:password`` a line) lets in only the users listed there.
- **Access control** (``access_control``, ``robocloud.federation.security.policy``),
  on a cloud's router when TLS or credentials are on.

``OverlaySecurity.apply`` adds these to a ``zenoh.Config``;
``robocloud.fleet.zenoh_session`` calls it (``open_router(..., security=)``,
``open_client(..., security=)``) and opens ``tcp/`` endpoints as ``tls/``.
``add_arguments`` and ``from_arguments`` are the flags of ``robocloud iaas``
and ``robocloud sim`` (``--tls-ca``, ``--tls-cert``, ``--tls-key``,
``--zenoh-user``, ``--zenoh-password-file``, ``--zenoh-credentials``,
``--robot-ids``).
See docs/security.md.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from robocloud.errors import InvalidInput

if TYPE_CHECKING:  # only for annotations: the command-line parser stays quick to import
    import zenoh

_CERT_BEGIN = "-----BEGIN CERTIFICATE-----"
_KEY_END = "PRIVATE KEY-----"


@dataclass(frozen=True)
class OverlaySecurity:
    """TLS files, credentials and (for a cloud's router) whom to trust with commands.

    ``ca`` alone: TLS that checks the router's certificate (a client of a
    router that does not ask for one). ``ca`` with ``cert`` and ``key``:
    mutual TLS, what the IaaS routers use and require of everyone joining.
    ``user`` and ``password``: the credentials this session shows.
    ``credentials``: the file of the users a router lets in.
    ``cloud`` and ``trusted`` (set by ``for_cloud``): the access control.
    ``robot_ids``: the robots of this router's cloud that have a certificate
    of their own (``<cloud>-robot-<id>``): each may speak for itself only.
    ``gateways``: the gateways of this router's cloud that have a certificate
    of their own (``<cloud>-gateway-<name>``), each with the robots it fronts:
    each may speak for those robots only.
    """

    ca: Path | None = None
    cert: Path | None = None
    key: Path | None = None
    user: str | None = None
    password: str | None = field(default=None, repr=False)
    credentials: Path | None = None
    cloud: str | None = None
    trusted: tuple[str, ...] = ()
    robot_ids: tuple[str, ...] = ()
    gateways: tuple[tuple[str, tuple[str, ...]], ...] = ()

    def __post_init__(self) -> None:
        for name in ("ca", "cert", "key", "credentials"):
            value = getattr(self, name)
            if isinstance(value, str):
                object.__setattr__(self, name, Path(value))
        object.__setattr__(self, "trusted", tuple(self.trusted))
        object.__setattr__(self, "robot_ids", tuple(self.robot_ids))
        object.__setattr__(
            self, "gateways", tuple((name, tuple(ids)) for name, ids in self.gateways)
        )
        if self.robot_ids and self.cert is None:
            raise InvalidInput(
                "robots with their own certificate (--robot-ids) need mutual TLS: give this "
                "router its certificate (--tls-ca, --tls-cert, --tls-key).",
                field="robot_ids",
            )
        if self.gateways and self.cert is None:
            raise InvalidInput(
                "gateways with their own certificate (--gateways) need mutual TLS: give this "
                "router its certificate (--tls-ca, --tls-cert, --tls-key).",
                field="gateways",
            )
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
        robot_ids_file: str | Path | None = None,
        gateways_file: str | Path | None = None,
    ) -> OverlaySecurity | None:
        """The security the command-line options ask for; None when they ask for none.

        The password is read from a file (its first line), never from the
        command line, where other users of the machine could see it.
        """
        password = None
        if password_file is not None:
            path = Path(password_file)
            lines = _read_text(path, "Zenoh password file", "password").splitlines()
            password = lines[0] if lines else ""
        robot_ids = read_robot_ids(Path(robot_ids_file)) if robot_ids_file is not None else ()
        gateways = read_gateways(Path(gateways_file)) if gateways_file is not None else ()
        files = (credentials, robot_ids_file, gateways_file)
        if all(v is None for v in (ca, cert, key, user, password, *files)):
            return None
        return cls(
            ca=Path(ca) if ca is not None else None,
            cert=Path(cert) if cert is not None else None,
            key=Path(key) if key is not None else None,
            user=user,
            password=password,
            credentials=Path(credentials) if credentials is not None else None,
            robot_ids=robot_ids,
            gateways=gateways,
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

        With mutual TLS ``trusted`` must name at least one cloud: the router
        gives each trusted cloud's certificate the command keys that name it
        (``policy.check_trusted``). With logins only, empty means every peer
        let in (as ``Settings.trusted`` empty means in ``robocloud.iaas``).
        """
        from robocloud.federation.security.policy import check_trusted

        names = check_trusted(cloud, tuple(trusted), self.mutual_tls)
        return replace(self, cloud=cloud, trusted=names)

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
            from robocloud.federation.security.policy import access_control

            entries["access_control"] = access_control(
                self.cloud,
                self.trusted,
                by_certificate=self.mutual_tls,
                robot_ids=self.robot_ids,
                gateways=self.gateways,
            )
        return entries


def read_credentials(path: Path) -> dict[str, str]:
    """The ``user:password`` lines of a credentials file, checked as Zenoh reads them."""
    text = _read_text(path, "Zenoh credentials file", "credentials")
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


def read_robot_ids(path: Path) -> tuple[str, ...]:
    """The ids of a ``--robot-ids`` file: one a line; blank lines and ``#`` comments skipped."""
    from robocloud.federation.security.policy import check_robot_ids

    text = _read_text(path, "robot ids file", "robot_ids")
    ids = [line.strip() for line in text.splitlines()]
    ids = [rid for rid in ids if rid and not rid.startswith("#")]
    if not ids:
        raise InvalidInput(f"the robot ids file {path} lists no robot id.", field="robot_ids")
    return check_robot_ids(ids)


def read_gateways(path: Path) -> tuple[tuple[str, tuple[str, ...]], ...]:
    """The gateways of a ``--gateways`` file: a gateway a line, its name then the ids of
    the robots it fronts, separated by spaces; blank lines and ``#`` comments skipped."""
    from robocloud.federation.security.policy import check_gateways

    text = _read_text(path, "gateways file", "gateways")
    gateways = []
    for number, line in enumerate(text.splitlines(), 1):
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        if len(words) < 2:
            raise InvalidInput(
                f"line {number} of the gateways file {path} names gateway {words[0]!r} but no "
                "robot: write the gateway's name, then the ids of the robots it fronts.",
                field="gateways",
            )
        gateways.append((words[0], tuple(words[1:])))
    if not gateways:
        raise InvalidInput(f"the gateways file {path} lists no gateway.", field="gateways")
    return check_gateways(gateways)


def _read_text(path: Path, what: str, field: str) -> str:
    """The text of a settings file, or InvalidInput with a sentence naming ``what``."""
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InvalidInput(f"the {what} {path} does not exist.", field=field) from None
    except (OSError, UnicodeDecodeError) as error:
        raise InvalidInput(f"cannot read the {what} {path}: {error}.", field=field) from error


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
        group.add_argument(
            "--robot-ids",
            metavar="FILE",
            help="robot ids, one a line, of this cloud's robots that have their own certificate "
            "(common name CLOUD-robot-ID): each may put only its own state and answer only its "
            "own commands (needs --tls-cert; read at start)",
        )
        group.add_argument(
            "--gateways",
            metavar="FILE",
            help="a gateway a line: its name, then the ids of the robots it fronts, of this "
            "cloud's gateways that have their own certificate (common name "
            "CLOUD-gateway-NAME): each may speak only for its robots (needs --tls-cert; read "
            "at start)",
        )


def from_arguments(args: argparse.Namespace) -> OverlaySecurity | None:
    """The security the flags of ``add_arguments`` ask for; None when they ask for none.

    For a router (``robocloud iaas``: ``args`` has ``cloud`` and ``trust``),
    also checks now, before anything starts, that the trusted clouds fit the
    access control it will get.
    """
    security = OverlaySecurity.from_options(
        ca=args.tls_ca,
        cert=args.tls_cert,
        key=args.tls_key,
        user=args.zenoh_user,
        password_file=args.zenoh_password_file,
        credentials=getattr(args, "zenoh_credentials", None),
        robot_ids_file=getattr(args, "robot_ids", None),
        gateways_file=getattr(args, "gateways", None),
    )
    cloud, trusted = getattr(args, "cloud", None), getattr(args, "trust", None)
    if security is not None and cloud is not None and trusted is not None:
        security.for_cloud(cloud, trusted)
    return security
