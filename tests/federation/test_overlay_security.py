"""Security between clouds, with real Zenoh routers on loopback.

Mutual TLS with certificates of one CA, Zenoh user-password credentials, and
the access control that lets each trusted cloud send commands for a cloud's
robots only on the keys that name it (recognised by its certificate), so the
sender a home reads from the key is the cloud that sent it.

Why one long file: its tests share the certificate authority and the
routers it makes; a table of who may do what reads best in one place.
"""

from __future__ import annotations

import argparse
import json
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import zenoh

from loopback_ports import free_endpoint
from robocloud.errors import InvalidInput
from robocloud.federation import keys
from robocloud.federation.keys import CLOUDS_TOKEN
from robocloud.federation.messages import (
    CloudInfo,
    Dispatch,
    Done,
    FleetReply,
    IdleQuery,
    IdleReply,
    LoanQuery,
    LoanReply,
    Release,
    RequestStatus,
    Reservation,
    ReserveReply,
    StatusQuery,
    StatusReply,
)
from robocloud.federation.overlay import Unreachable, ZenohOverlay
from robocloud.federation.security import (
    COMMANDS,
    QUESTIONS,
    OverlaySecurity,
    access_control,
    add_arguments,
    from_arguments,
    main,
    make_certs,
    read_credentials,
)
from robocloud.fleet.messages import Ack, Assign
from robocloud.fleet.zenoh_session import (
    open_client,
    open_router,
    secure_endpoints,
    wait_for_liveliness,
)

NAMES = ("cloud-a", "cloud-b", "cloud-c", "cloud-b-robots")


def ask(session: zenoh.Session, key: str, payload: str | None = None) -> list[str]:
    """The payloads of the ok replies to one query."""
    replies = session.get(key, payload=payload, timeout=0.5)
    return [r.ok.payload.to_string() for r in replies if r.ok is not None]


def ask_until(session: zenoh.Session, key: str, tries: int = 40) -> list[str]:
    """Replies to a query retried until some come (routes take a moment after a join)."""
    for _ in range(tries):
        got = ask(session, key)
        if got:
            return got
        time.sleep(0.05)
    return []


def answer(session: zenoh.Session, key: str, text: str) -> zenoh.Queryable[None]:
    return session.declare_queryable(key, lambda query: query.reply(query.key_expr, text))


@dataclass
class Pki:
    dir: Path
    other_ca: Path  # a second CA, the federation does not know it

    def security(self, name: str | None, **more: object) -> OverlaySecurity:
        if name is None:
            return OverlaySecurity(ca=self.dir / "ca.pem", **more)  # type: ignore[arg-type]
        return OverlaySecurity(
            ca=self.dir / "ca.pem",
            cert=self.dir / f"{name}.pem",
            key=self.dir / f"{name}.key",
            **more,  # type: ignore[arg-type]
        )

    def rogue(self, name: str) -> OverlaySecurity:
        """A certificate with a good name signed by another CA."""
        return OverlaySecurity(
            ca=self.dir / "ca.pem",
            cert=self.other_ca / f"{name}.pem",
            key=self.other_ca / f"{name}.key",
        )


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    root = tmp_path_factory.mktemp("pki")
    make_certs(root / "federation", NAMES, days=2)
    make_certs(root / "rogue", ["cloud-a"], days=2)
    return Pki(root / "federation", root / "rogue")


@pytest.fixture
def sessions() -> Iterator[Callable[[zenoh.Session], zenoh.Session]]:
    """Closes every session a test keeps, last opened first."""
    opened: list[zenoh.Session] = []

    def keep(session: zenoh.Session) -> zenoh.Session:
        opened.append(session)
        return session

    yield keep
    for session in reversed(opened):
        session.close()  # type: ignore[no-untyped-call]


# -- validation, without Zenoh ----------------------------------------------------


def test_nothing_asked_means_no_security() -> None:
    assert OverlaySecurity.from_options() is None
    assert secure_endpoints(["tcp/127.0.0.1:7447"], None, "listen") == ["tcp/127.0.0.1:7447"]


def test_files_must_exist_and_come_in_pairs(pki: Pki, tmp_path: Path) -> None:
    ca, cert, key = pki.dir / "ca.pem", pki.dir / "cloud-a.pem", pki.dir / "cloud-a.key"
    with pytest.raises(InvalidInput, match="go together"):
        OverlaySecurity(ca=ca, cert=cert)
    with pytest.raises(InvalidInput, match="needs the CA"):
        OverlaySecurity(cert=cert, key=key)
    with pytest.raises(InvalidInput, match="does not exist"):
        OverlaySecurity(ca=tmp_path / "missing.pem")
    with pytest.raises(InvalidInput, match="not a PEM private key"):
        OverlaySecurity(ca=ca, cert=cert, key=cert)
    with pytest.raises(InvalidInput, match="not a PEM CA certificate"):
        OverlaySecurity(ca=key)
    with pytest.raises(InvalidInput, match="user and password go together"):
        OverlaySecurity(user="cloud-a")
    with pytest.raises(InvalidInput, match="without spaces or colons"):
        OverlaySecurity(user="cloud:a", password="x")


def test_the_command_line_flags_build_the_security(pki: Pki, tmp_path: Path) -> None:
    parser = argparse.ArgumentParser()
    add_arguments(parser, router=True)
    assert from_arguments(parser.parse_args([])) is None
    secret = tmp_path / "password"
    secret.write_text("pb\n")
    users = tmp_path / "users"
    users.write_text("cloud-a:pa\n")
    args = parser.parse_args(
        [
            "--tls-ca", str(pki.dir / "ca.pem"),
            "--tls-cert", str(pki.dir / "cloud-b.pem"),
            "--tls-key", str(pki.dir / "cloud-b.key"),
            "--zenoh-user", "cloud-b",
            "--zenoh-password-file", str(secret),
            "--zenoh-credentials", str(users),
        ]
    )  # fmt: skip
    security = from_arguments(args)
    assert security == OverlaySecurity(
        pki.dir / "ca.pem", pki.dir / "cloud-b.pem", pki.dir / "cloud-b.key", "cloud-b", "pb", users
    )
    robots = argparse.ArgumentParser()
    add_arguments(robots, router=False)
    assert from_arguments(robots.parse_args(["--tls-ca", str(pki.dir / "ca.pem")])) == (
        OverlaySecurity(ca=pki.dir / "ca.pem")
    )
    with pytest.raises(SystemExit):
        robots.parse_args(["--zenoh-credentials", str(users)])


def test_the_password_comes_from_a_file(tmp_path: Path) -> None:
    secret = tmp_path / "password"
    secret.write_text("s3cret\n")
    security = OverlaySecurity.from_options(user="cloud-a", password_file=secret)
    assert security is not None and security.password == "s3cret"
    assert "s3cret" not in repr(security)
    with pytest.raises(InvalidInput, match="does not exist"):
        OverlaySecurity.from_options(user="cloud-a", password_file=tmp_path / "nope")


def test_credentials_files_are_read_as_zenoh_reads_them(tmp_path: Path) -> None:
    good = tmp_path / "good"
    good.write_text("cloud-a:pa\ncloud-b: p:b\n")
    assert read_credentials(good) == {"cloud-a": "pa", "cloud-b": "p:b"}
    for text in ("# clouds\ncloud-a:pa\n", "cloud-a:pa\n\ncloud-b:pb\n", "cloud-a\n", ""):
        bad = tmp_path / "bad"
        bad.write_text(text)
        with pytest.raises(InvalidInput, match="credentials file"):
            OverlaySecurity(credentials=bad)


def test_tls_turns_tcp_endpoints_into_tls_and_refuses_clear_ones(pki: Pki) -> None:
    security = pki.security("cloud-a")
    assert secure_endpoints(["tcp/127.0.0.1:1", "tls/h:2", "quic/h:3"], security, "listen") == [
        "tls/127.0.0.1:1",
        "tls/h:2",
        "quic/h:3",
    ]
    with pytest.raises(InvalidInput, match="would not be encrypted"):
        secure_endpoints(["udp/127.0.0.1:1"], security, "listen")


def test_a_tls_router_needs_its_own_certificate(pki: Pki) -> None:
    with pytest.raises(InvalidInput, match="needs its own certificate"):
        open_router([free_endpoint()], security=pki.security(None))


def test_a_router_with_a_login_needs_the_list_of_logins_it_accepts() -> None:
    with pytest.raises(InvalidInput, match="credentials file"):
        open_router([free_endpoint()], security=OverlaySecurity(user="cloud-a", password="pa"))


def test_access_control_is_off_without_a_way_to_know_peers(pki: Pki) -> None:
    assert "access_control" not in pki.security(None).for_cloud("cloud-b").config_entries("router")
    entries = pki.security("cloud-b").for_cloud("cloud-b", ["cloud-a"]).config_entries("router")
    assert entries["access_control"]["default_permission"] == "deny"
    assert "access_control" not in pki.security("cloud-b-robots").config_entries("client")


def test_each_trusted_cloud_gets_only_the_command_keys_that_name_it() -> None:
    acl = access_control("cloud-b", ["cloud-c", "cloud-a"])
    rules = {rule["id"]: rule for rule in acl["rules"]}
    policies = {policy["id"]: policy for policy in acl["policies"]}
    for name in ("cloud-a", "cloud-c"):
        assert rules[f"commands-from-{name}"]["key_exprs"] == [
            f"robocloud/cloud-b/from/{name}/{c}" for c in COMMANDS
        ]
        # As a cloud: its own presence, answers and robots' states, nobody else's.
        assert rules[f"presence-of-{name}"]["key_exprs"] == [
            f"robocloud/federation/clouds/{name}/*"
        ]
        assert rules[f"answers-of-{name}"]["key_exprs"] == [f"robocloud/{name}/**"]
        assert {"id": f"cloud-{name}", "cert_common_names": [name]} in acl["subjects"]
        assert policies[f"trusted-{name}"]["subjects"] == [f"cloud-{name}"]
    assert rules["answer"]["key_exprs"] == [f"robocloud/*/{q}" for q in QUESTIONS]
    assert policies["anyone"]["rules"] == ["out", "listen", "answer"]  # no command, no put
    # The fleet's certificate: its cloud's robot keys only.
    assert {"id": "fleet", "cert_common_names": ["cloud-b-robots"]} in acl["subjects"]
    assert rules["fleet-states"]["key_exprs"] == [
        "robocloud/cloud-b/robots/*/state",
        "robocloud/cloud-b/fleets/*/states",
    ]
    assert rules["fleet-commands"]["messages"] == ["declare_queryable", "reply"]
    assert json.loads(json.dumps(acl)) == acl
    # A router knows the user name only of peers that connected to it: by
    # user name, commands stay open to every peer let in (docs/security.md).
    by_user = access_control("cloud-b", [], by_certificate=False)
    assert "commands" in by_user["policies"][0]["rules"]
    assert {r["id"]: r for r in by_user["rules"]}["commands"]["key_exprs"] == [
        f"robocloud/cloud-b/from/*/{c}" for c in COMMANDS
    ]


def test_with_certificates_a_router_must_trust_someone(pki: Pki) -> None:
    """An empty --trust would give the command keys to every member, robots included."""
    with pytest.raises(InvalidInput, match="name them with --trust CLOUD"):
        pki.security("cloud-b").for_cloud("cloud-b", [])
    with pytest.raises(InvalidInput, match="cannot be used in a Zenoh key"):
        pki.security("cloud-b").for_cloud("cloud-b", ["cloud/*"])
    parser = argparse.ArgumentParser()
    parser.add_argument("--cloud")
    parser.add_argument("--trust", action="append", default=[])
    add_arguments(parser, router=True)
    flags = [
        "--cloud", "cloud-b",
        "--tls-ca", str(pki.dir / "ca.pem"),
        "--tls-cert", str(pki.dir / "cloud-b.pem"),
        "--tls-key", str(pki.dir / "cloud-b.key"),
    ]  # fmt: skip
    with pytest.raises(InvalidInput, match="trusts none"):
        from_arguments(parser.parse_args(flags))
    assert from_arguments(parser.parse_args([*flags, "--trust", "cloud-a"])) is not None


def test_make_certs_cli_writes_a_ca_and_private_keys(tmp_path: Path) -> None:
    assert main(["make-certs", "--out", str(tmp_path), "--host", "iaas.example.org", "x-1"]) == 0
    assert (tmp_path / "ca.pem").read_text().startswith("-----BEGIN CERTIFICATE-----")
    assert (tmp_path / "x-1.key").stat().st_mode & 0o077 == 0
    assert main(["make-certs", "--out", str(tmp_path), "x-1"]) == 2  # never overwrites
    assert main(["make-certs", "--out", str(tmp_path), "x-2"]) == 0  # reuses the CA


# -- mutual TLS ---------------------------------------------------------------------


def test_routers_with_certificates_of_one_ca_answer_each_other(
    pki: Pki, sessions: Callable[[zenoh.Session], zenoh.Session]
) -> None:
    a_endpoint = free_endpoint()
    a = sessions(open_router([a_endpoint], security=pki.security("cloud-a")))
    b = sessions(open_router([free_endpoint()], [a_endpoint], security=pki.security("cloud-b")))
    kept = answer(a, "robocloud/cloud-a/info", "a")
    assert ask_until(b, "robocloud/cloud-a/info") == ["a"]
    robot = sessions(open_client([a_endpoint], security=pki.security("cloud-b-robots")))
    assert ask_until(robot, "robocloud/cloud-a/info") == ["a"]
    kept.undeclare()  # type: ignore[no-untyped-call]


def test_without_a_certificate_of_the_ca_nothing_gets_in(
    pki: Pki, sessions: Callable[[zenoh.Session], zenoh.Session]
) -> None:
    a_endpoint = free_endpoint()
    a = sessions(open_router([a_endpoint], security=pki.security("cloud-a")))
    kept = answer(a, "robocloud/cloud-a/info", "a")
    with pytest.raises(InvalidInput, match="cannot open a Zenoh session"):
        open_client([a_endpoint])  # plain TCP to a TLS port
    with pytest.raises(InvalidInput, match="certificate"):
        open_client([a_endpoint], security=pki.security(None))  # TLS, no certificate
    with pytest.raises(InvalidInput, match="certificate"):
        open_client([a_endpoint], security=pki.rogue("cloud-a"))  # the name, another CA
    # A router retries its peers in the background: it opens, but hears nothing.
    rogue = sessions(open_router([free_endpoint()], [a_endpoint], security=pki.rogue("cloud-a")))
    assert ask_until(rogue, "robocloud/cloud-a/info", tries=4) == []
    kept.undeclare()  # type: ignore[no-untyped-call]


# -- credentials ----------------------------------------------------------------------


def test_a_peer_with_a_wrong_password_cannot_join(
    tmp_path: Path, sessions: Callable[[zenoh.Session], zenoh.Session]
) -> None:
    users = tmp_path / "users"
    users.write_text("cloud-a:pa\ncloud-b:pb\ncloud-c:pc\n")

    def login(user: str, password: str) -> OverlaySecurity:
        return OverlaySecurity(user=user, password=password, credentials=users)

    a_endpoint = free_endpoint()
    a = sessions(open_router([a_endpoint], security=login("cloud-a", "pa")))
    kept = answer(a, "robocloud/cloud-a/info", "a")
    b = sessions(open_router([free_endpoint()], [a_endpoint], security=login("cloud-b", "pb")))
    assert ask_until(b, "robocloud/cloud-a/info") == ["a"]
    c = sessions(open_router([free_endpoint()], [a_endpoint], security=login("cloud-c", "pb")))
    assert ask_until(c, "robocloud/cloud-a/info", tries=4) == []
    with pytest.raises(InvalidInput, match="cannot open a Zenoh session"):
        open_client([a_endpoint], security=OverlaySecurity(user="cloud-c", password="nope"))
    with pytest.raises(InvalidInput, match="cannot open a Zenoh session"):
        open_client([a_endpoint])
    robot = sessions(
        open_client([a_endpoint], security=OverlaySecurity(user="cloud-c", password="pc"))
    )
    assert ask_until(robot, "robocloud/cloud-a/info") == ["a"]
    kept.undeclare()  # type: ignore[no-untyped-call]


def test_with_credentials_only_commands_stay_open_but_robots_closed(
    tmp_path: Path, sessions: Callable[[zenoh.Session], zenoh.Session]
) -> None:
    users = tmp_path / "users"
    users.write_text("cloud-b:pb\ncloud-c:pc\n")
    b_endpoint = free_endpoint()
    b_security = OverlaySecurity(user="cloud-b", password="pb", credentials=users)
    b = sessions(open_router([b_endpoint], security=b_security.for_cloud("cloud-b", ["cloud-a"])))
    kept = [
        answer(b, "robocloud/cloud-b/from/*/dispatch", "dispatched"),
        answer(b, "robocloud/cloud-b/robots/b-1/cmd", "ack"),
    ]
    c_security = OverlaySecurity(user="cloud-c", password="pc", credentials=users)
    c = sessions(open_router([free_endpoint()], [b_endpoint], security=c_security))
    # Users are known only to the router they connect to: --trust cannot be
    # enforced by Zenoh here, so the command keys stay open to every login.
    assert ask_until(c, "robocloud/cloud-b/from/cloud-c/dispatch") == ["dispatched"]
    assert ask(c, "robocloud/cloud-b/robots/b-1/cmd") == []
    for queryable in kept:
        queryable.undeclare()  # type: ignore[no-untyped-call]


# -- access control: commands only from trusted clouds ----------------------------------


@dataclass
class Desk:
    """A HomeDesk that answers everything and records the commands it gets, with their sender."""

    cloud: str
    commands: list[tuple[str, str]] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def _got(self, name: str, origin: str) -> None:
        with self.lock:
            self.commands.append((name, origin))

    def trusts(self, cloud: str) -> bool:
        return True

    def info(self) -> CloudInfo:
        return CloudInfo(cloud=self.cloud, robots=1, idle=1)

    def idle_robots(self, query: IdleQuery) -> bytes:
        return IdleReply(cloud=self.cloud, robots=[]).model_dump_json().encode()

    def fleet(self) -> FleetReply:
        return FleetReply(cloud=self.cloud, robots=[])

    def status(self, query: StatusQuery) -> StatusReply:
        return StatusReply(
            requests=[RequestStatus(request_id=r, known=False) for r in query.request_ids]
        )

    def reserve(self, origin: str, reservation: Reservation) -> ReserveReply:
        self._got("reserve", origin)
        return ReserveReply()

    def confirm(self, origin: str, reservation: Reservation) -> ReserveReply:
        self._got("confirm", origin)
        return ReserveReply()

    def release(self, origin: str, release: Release) -> Done:
        self._got("release", origin)
        return Done()

    def dispatch(self, origin: str, dispatch: Dispatch) -> Ack:
        self._got("dispatch", origin)
        return Ack(ok=True, robot=dispatch.robot, request_id=dispatch.command.request_id)

    def cancel(self, origin: str, release: Release) -> Done:
        self._got("cancel", origin)
        return Done()

    def loans(self, origin: str, query: LoanQuery) -> LoanReply:
        self._got("loans", origin)
        return LoanReply(cloud=self.cloud)


GO = Assign(request_id="r-1", location=[1.0, 2.0], capabilities=["grabber"])


@dataclass
class Federation:
    endpoints: dict[str, str]
    routers: dict[str, zenoh.Session]
    desks: dict[str, Desk]
    overlays: dict[str, ZenohOverlay]


@pytest.fixture
def federation(
    pki: Pki, sessions: Callable[[zenoh.Session], zenoh.Session]
) -> Iterator[Federation]:
    """Three clouds in a full mesh with mutual TLS: b trusts a and c; c trusts only a."""
    endpoints = {name: free_endpoint() for name in ("cloud-a", "cloud-b", "cloud-c")}
    trust: dict[str, list[str]] = {
        "cloud-a": ["cloud-b", "cloud-c"],
        "cloud-b": ["cloud-a", "cloud-c"],
        "cloud-c": ["cloud-a"],
    }
    routers: dict[str, zenoh.Session] = {}
    for name, endpoint in endpoints.items():
        security = pki.security(name).for_cloud(name, trust[name])
        earlier = [endpoints[other] for other in routers]
        routers[name] = sessions(open_router([endpoint], earlier, security))
    desks = {name: Desk(name) for name in routers}
    overlays = {
        name: ZenohOverlay(session, name, desks[name], timeout=0.5)
        for name, session in routers.items()
    }
    # Each router lets in the presence of the clouds it trusts only.
    seen = {name: sorted({name, *trust[name]}) for name in routers}
    for name, session in routers.items():
        for other in seen[name]:
            assert wait_for_liveliness(session, f"{CLOUDS_TOKEN}/{other}/*", 5.0)
    # Each overlay learns the tokens from its own subscriber, a moment later.
    deadline = time.monotonic() + 5.0
    while any(o.clouds() != seen[n] for n, o in overlays.items()):
        assert time.monotonic() < deadline, {n: o.clouds() for n, o in overlays.items()}
        time.sleep(0.02)
    yield Federation(endpoints, routers, desks, overlays)
    for overlay in overlays.values():
        overlay.close()


def test_the_sender_is_the_one_the_key_names(federation: Federation) -> None:
    desks = federation.desks
    a, c = federation.overlays["cloud-a"], federation.overlays["cloud-c"]
    assert a.dispatch("cloud-b", Dispatch(robot="b-1", command=GO)).ok
    assert a.reserve("cloud-b", Reservation(request_id="r-1", robots=["b-1"])).taken == []
    # A payload that claims another origin changes nothing: the key decides.
    claim = json.dumps({"origin": "cloud-c", "request_id": "r-1", "robots": ["b-1"]})
    release = keys.command("cloud-b", "cloud-a", "release")
    assert len(ask(federation.routers["cloud-a"], release, claim)) == 1
    assert desks["cloud-b"].commands == [
        ("dispatch", "cloud-a"),
        ("reserve", "cloud-a"),
        ("release", "cloud-a"),
    ]
    # cloud-c, trusting only cloud-a, does not even see cloud-b's command keys.
    assert ask(federation.routers["cloud-c"], keys.command("cloud-b", "cloud-c", "loans")) == []
    assert a.loans("cloud-b", LoanQuery()).cloud == "cloud-b"
    assert desks["cloud-b"].commands[-1] == ("loans", "cloud-a")
    with pytest.raises(Unreachable, match="not a cloud cloud-c trusts"):
        c.loans("cloud-b", LoanQuery())


def test_a_cloud_cannot_send_as_another(federation: Federation) -> None:
    """cloud-c, trusted by cloud-b, sends on the keys that name cloud-a: the router drops them."""
    c_router, desks = federation.routers["cloud-c"], federation.desks
    payloads = {
        "reserve": Reservation(request_id="r-1", robots=["b-1"]).model_dump_json(),
        "confirm": Reservation(request_id="r-1", robots=["b-1"]).model_dump_json(),
        "release": Release(request_id="r-1").model_dump_json(),
        "cancel": Release(request_id="r-1").model_dump_json(),
        "dispatch": Dispatch(robot="b-1", command=GO).model_dump_json(),
        "loans": LoanQuery().model_dump_json(),
    }
    for name, payload in payloads.items():
        assert ask(c_router, keys.command("cloud-b", "cloud-a", name), payload) == []
        assert ask(c_router, keys.command("cloud-b", "*", name), payload) == []
    assert desks["cloud-b"].commands == []
    # ... while cloud-a's own commands pass.
    loans = keys.command("cloud-b", "cloud-a", "loans")
    assert len(ask(federation.routers["cloud-a"], loans, payloads["loans"])) == 1
    assert desks["cloud-b"].commands == [("loans", "cloud-a")]


def test_an_untrusted_cloud_sends_no_command(federation: Federation) -> None:
    b = federation.overlays["cloud-b"]
    with pytest.raises(Unreachable):
        b.reserve("cloud-c", Reservation(request_id="r-1", robots=["c-1"]))
    refused = b.dispatch("cloud-c", Dispatch(robot="c-1", command=GO))
    assert not refused.ok and "not reachable" in (refused.error or "")
    assert federation.desks["cloud-c"].commands == []
    assert federation.overlays["cloud-a"].release("cloud-c", Release(request_id="r-2")).ok
    assert federation.desks["cloud-c"].commands == [("release", "cloud-a")]


def test_a_cloud_hears_only_the_clouds_it_trusts(federation: Federation) -> None:
    """cloud-c trusts cloud-a only: cloud-b's presence and answers never reach it."""
    c, b = federation.overlays["cloud-c"], federation.overlays["cloud-b"]
    assert c.clouds() == ["cloud-a", "cloud-c"]
    assert [info.cloud for info in c.infos()] == ["cloud-a", "cloud-c"]
    assert sorted(c.gather_idle(IdleQuery(origin="cloud-c")).replies) == ["cloud-a"]
    with pytest.raises(Unreachable, match="not a cloud cloud-c trusts"):
        c.status("cloud-b", StatusQuery(home="cloud-c", request_ids=["r-9"]))
    # cloud-b trusts cloud-c, and hears its answers to the questions.
    assert b.clouds() == ["cloud-a", "cloud-b", "cloud-c"]
    status = b.status("cloud-c", StatusQuery(home="cloud-b", request_ids=["r-9"]))
    assert [s.known for s in status.requests] == [False]


def test_wide_queries_and_robot_keys_are_closed_to_other_clouds(
    pki: Pki, federation: Federation, sessions: Callable[[zenoh.Session], zenoh.Session]
) -> None:
    routers, desks = federation.routers, federation.desks
    robot = sessions(
        open_client([federation.endpoints["cloud-b"]], security=pki.security("cloud-b-robots"))
    )
    kept = answer(robot, "robocloud/cloud-b/robots/*/cmd", "ack")
    # cloud-b's IaaS (the router's own session) reaches its robots.
    assert ask_until(routers["cloud-b"], "robocloud/cloud-b/robots/b-1/cmd") == ["ack"]
    payload = Dispatch(robot="b-1", command=GO).model_dump_json()
    # Keys that include cloud-b's command keys, which a deny rule would miss.
    for key in ("robocloud/**", "robocloud/cloud-b/**", "robocloud/*/from/*/dispatch"):
        ask(routers["cloud-c"], key, payload)
    # Nobody else queries a robot directly, not even a trusted cloud.
    for name in ("cloud-a", "cloud-c"):
        assert ask(routers[name], "robocloud/cloud-b/robots/b-1/cmd") == []
    # A robot's certificate sends no cloud command, as any cloud or as itself.
    for sender in ("cloud-b-robots", "cloud-a", "cloud-b", "*"):
        assert ask(robot, keys.command("cloud-b", sender, "dispatch"), payload) == []
    assert desks["cloud-b"].commands == []
    # cloud-b's own tools, with its certificate, may ask anything of it.
    tool = sessions(
        open_client([federation.endpoints["cloud-b"]], security=pki.security("cloud-b"))
    )
    assert ask_until(tool, "robocloud/cloud-b/robots/b-1/cmd") == ["ack"]
    assert len(ask(tool, keys.command("cloud-b", "cloud-a", "dispatch"), payload)) == 1
    assert desks["cloud-b"].commands == [("dispatch", "cloud-a")]
    kept.undeclare()  # type: ignore[no-untyped-call]


# -- identities the router enforces: attacks with legitimate certificates ---------------


def test_a_robot_certificate_cannot_fabricate_or_answer_for_a_cloud(
    pki: Pki, federation: Federation, sessions: Callable[[zenoh.Session], zenoh.Session]
) -> None:
    """cloud-b's robots' certificate on cloud-a's router: presence tokens for cloud-zzz and
    cloud-b, answers on their keys, states on cloud-b's keys. cloud-a's router drops them all."""
    a_router, a = federation.routers["cloud-a"], federation.overlays["cloud-a"]
    robot = sessions(
        open_client([federation.endpoints["cloud-a"]], security=pki.security("cloud-b-robots"))
    )
    zid = str(robot.zid())
    kept = [
        robot.liveliness().declare_token(keys.cloud_token("cloud-zzz", zid)),
        robot.liveliness().declare_token(keys.cloud_token("cloud-b", zid)),
        answer(robot, "robocloud/cloud-zzz/info", '{"cloud": "cloud-zzz", "robots": 3, "idle": 3}'),
        answer(robot, "robocloud/cloud-b/status", '{"requests": []}'),
    ]
    heard: list[str] = []
    states = a_router.declare_subscriber(
        "robocloud/*/robots/*/state", lambda sample: heard.append(str(sample.key_expr))
    )
    robot.put("robocloud/cloud-b/robots/b-1/state", "{}")
    # A control the router does let in: the robot's liveliness subscription.
    assert wait_for_liveliness(robot, f"{CLOUDS_TOKEN}/cloud-a/*", 5.0)
    assert not wait_for_liveliness(a_router, f"{CLOUDS_TOKEN}/cloud-zzz/*", 0.5)
    assert a.clouds() == ["cloud-a", "cloud-b", "cloud-c"]
    assert [info.cloud for info in a.infos()] == ["cloud-a", "cloud-b", "cloud-c"]
    status = a.status("cloud-b", StatusQuery(home="cloud-a", request_ids=["r-1"]))
    assert [s.known for s in status.requests] == [False]  # cloud-b's Desk: known False
    assert a.presence.refusals() == {}  # nothing forged even reached the asker
    assert heard == []
    states.undeclare()  # type: ignore[no-untyped-call]
    for each in kept:
        each.undeclare()  # type: ignore[no-untyped-call]


def test_a_member_cloud_cannot_declare_or_answer_for_another(
    pki: Pki, federation: Federation, sessions: Callable[[zenoh.Session], zenoh.Session]
) -> None:
    """cloud-c's certificate (trusted by cloud-a) claims cloud-b's presence and answers
    cloud-b's status at cloud-a's router: dropped there."""
    a = federation.overlays["cloud-a"]
    member = sessions(
        open_client([federation.endpoints["cloud-a"]], security=pki.security("cloud-c"))
    )
    zid = str(member.zid())
    kept = [
        member.liveliness().declare_token(keys.cloud_token("cloud-b", zid)),
        answer(member, "robocloud/cloud-b/status", '{"requests": []}'),
        answer(member, "robocloud/cloud-b/from/*/reserve", '{"taken": ["b-1"], "error": "x"}'),
    ]
    # Its own keys pass (the control): a queryable on robocloud/cloud-c/... reaches cloud-a.
    own = answer(member, "robocloud/cloud-c/probe", "c")
    assert ask_until(federation.routers["cloud-a"], "robocloud/cloud-c/probe") == ["c"]
    assert a.clouds() == ["cloud-a", "cloud-b", "cloud-c"]  # cloud-b not disputed
    for _ in range(3):
        assert a.reserve("cloud-b", Reservation(request_id="r-1", robots=["b-1"])).taken == []
    assert a.presence.refusals() == {}
    for each in (*kept, own):
        each.undeclare()  # type: ignore[no-untyped-call]


def test_a_fleet_certificate_speaks_on_its_own_clouds_robot_keys(
    pki: Pki, federation: Federation, sessions: Callable[[zenoh.Session], zenoh.Session]
) -> None:
    """The control of the attacks above: cloud-b's robots at cloud-b's router are heard."""
    b_router = federation.routers["cloud-b"]
    heard: list[str] = []
    states = b_router.declare_subscriber(
        "robocloud/**", lambda sample: heard.append(str(sample.key_expr))
    )
    robot = sessions(
        open_client([federation.endpoints["cloud-b"]], security=pki.security("cloud-b-robots"))
    )
    kept = answer(robot, "robocloud/cloud-b/robots/b-1/cmd", "ack")
    assert ask_until(b_router, "robocloud/cloud-b/robots/b-1/cmd") == ["ack"]
    robot.put("robocloud/cloud-a/robots/a-1/state", "{}")  # another cloud's: dropped
    robot.put("robocloud/cloud-b/robots/b-1/state", "{}")
    deadline = time.monotonic() + 5.0
    while "robocloud/cloud-b/robots/b-1/state" not in heard:
        assert time.monotonic() < deadline, heard
        time.sleep(0.02)
    assert "robocloud/cloud-a/robots/a-1/state" not in heard
    states.undeclare()  # type: ignore[no-untyped-call]
    kept.undeclare()  # type: ignore[no-untyped-call]
