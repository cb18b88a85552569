"""Three clouds whose overlay runs on mutual TLS, as docs/security.md turns it on.

cloud-b lends its robots to cloud-a and cloud-c (``--trust cloud-a --trust
cloud-c``); cloud-a and cloud-c have no robots of their own. The flags of
``robocloud iaas`` and ``robocloud sim`` reach Zenoh: a request of cloud-a is
served by cloud-b's robots over ``tls/`` links; a simulator without a
certificate is kept out; cloud-c, trusted by cloud-b, cannot take or touch
cloud-a's loans there; a robot's certificate sends no cloud command; a
confirm without a lease is refused; and when cloud-a disappears, cloud-b
frees its robots after the deadline and tells cloud-a once it is back.

One set of clouds for the module (starting three TLS clouds takes a while):
the tests run in order, the last one kills and restarts cloud-a.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh
from processes import Cloud, follow, grabber_task, start_clouds, wait_until
from secure_clouds import repliers, session_as, tls_flags

from robocloud.federation import keys
from robocloud.federation.messages import Dispatch, LoanQuery, Release, Reservation
from robocloud.federation.security import OverlaySecurity, make_certs
from robocloud.fleet.messages import Assign

pytestmark = pytest.mark.slow

NAMES = ("cloud-a", "cloud-b", "cloud-c")
TRUST = {
    "cloud-a": ["cloud-b", "cloud-c"],
    "cloud-b": ["cloud-a", "cloud-c"],
    "cloud-c": ["cloud-a"],
}
# Every cloud's --origin-deadline, short for the test: cloud-b ends a loan of cloud-a's
# 1 s after cloud-a stops answering, and each cloud reconciles its loans every 0.25 s
# (a quarter of it): cloud-a, back, learns sooner what it lost.
DEADLINE = 1.0
OFFLINE_AFTER = 2.5  # cloud-b's --offline-after: a robot silent this long (5 s by default)
ROBOTS = 20  # cloud-b's; some start busy or charging (the simulator's roster)
# Robot seconds per wall second (the simulator's --speedup, the IaaSs' --time-scale):
# every grabber of cloud-b sent to (1000, 1000) is done in 4-5 s (857 robot seconds;
# 17 s at 50), and a far kicker is on its way for 4 s or more.
SPEEDUP = 200.0


@pytest.fixture(scope="module")
def federation(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[list[Cloud], Path]]:
    tmp_path = tmp_path_factory.mktemp("secure")
    certs = tmp_path / "certs"
    make_certs(certs, [*NAMES, "cloud-b-robots"])

    def iaas_args(name: str) -> list[str]:
        flags = [*tls_flags(certs, name), *(a for t in TRUST[name] for a in ("--trust", t))]
        flags += ["--origin-deadline", str(DEADLINE)]
        if name == "cloud-a":
            return flags
        # Sent no request, so selecting nothing: no selection worker processes to start.
        flags += ["--selection-workers", "0"]
        return [*flags, "--offline-after", str(OFFLINE_AFTER)] if name == "cloud-b" else flags

    clouds = start_clouds(
        tmp_path,
        NAMES,
        robots=0,
        speedup=SPEEDUP,
        iaas_args=iaas_args,
        sim_args=lambda name: tls_flags(certs, f"{name}-robots"),
        robots_at=lambda name: ROBOTS if name == "cloud-b" else 0,
        together=True,
    )
    try:
        yield clouds, certs
    finally:
        for cloud in clouds:
            cloud.stop()


def send(session: zenoh.Session, key: str, message: Any) -> list[dict[str, Any]]:
    """The replies (ok or error) to one command; none when a router refused it."""
    replies = session.get(key, payload=message.model_dump_json(), timeout=1.0)
    out = []
    for reply in replies:
        if reply.ok is not None:
            out.append(json.loads(reply.ok.payload.to_string()))
        elif reply.err is not None:
            out.append({"error": reply.err.payload.to_string()})
    return out


def log_of(cloud: Cloud) -> str:
    return (cloud.workdir / f"{cloud.name}-iaas.log").read_text()


def far_kicker_task(location: list[float]) -> dict[str, Any]:
    """One kicker, far from cloud-b's idle ones: on its way for 500 robot seconds or more
    (b-0005 drives 578 s to (1950, 1950), 1,009 s to (100, 100))."""
    return {
        "location": location,
        "actuating": {"kicker": 1},
        "max_robots": 1,
        "max_cost": 100_000.0,
        "max_time": 100_000.0,
        "min_battery": 20.0,
        "priority": "time",
    }


def start_far_request(a: Cloud, location: list[float]) -> tuple[str, str]:
    """cloud-a's request, underway with one robot of cloud-b: (request id, robot)."""
    with a.client() as client:
        rid = client.post("/v1/requests", json=far_kicker_task(location)).json()["id"]
        underway = follow(
            client, rid, lambda r: r["state"] in ("underway", "failed"), 30, "underway"
        )
    assert underway["state"] == "underway", underway
    [assigned] = underway["coalition"]
    assert assigned["cloud"] == "cloud-b"
    return rid, assigned["robot"]


def test_a_request_is_served_by_another_clouds_robots_over_tls(
    federation: tuple[list[Cloud], Path],
) -> None:
    (a, _, _), _ = federation
    with a.client() as client:
        task, homes = grabber_task(client)
        assert homes == {"cloud-b"}
        rid = client.post("/v1/requests", json=task).json()["id"]
        done = follow(
            client, rid, lambda r: r["state"] in ("completed", "failed", "rejected"), 90, "done"
        )
        assert done["state"] == "completed", done
        assert {x["cloud"] for x in done["coalition"]} == {"cloud-b"}


def test_a_simulator_without_a_certificate_is_kept_out(
    federation: tuple[list[Cloud], Path],
) -> None:
    (_, b, _), certs = federation
    # The CA but no certificate of its own: the router asks for one (mutual TLS).
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "robocloud.cli.main",
            "sim",
            "--cloud",
            "cloud-b",
            "--robots",
            "3",
            "--connect",
            b.zenoh,
            "--connect-timeout",
            "1",
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
    with b.client() as client:
        assert len(client.get("/v1/robots").json()) == ROBOTS


def test_cloud_c_can_neither_take_nor_touch_cloud_as_loans(
    federation: tuple[list[Cloud], Path],
) -> None:
    (a, b, _), certs = federation
    rid, robot = start_far_request(a, [100.0, 100.0])
    before = b.router_refusals().get(("cloud-c", "query"), 0.0)
    reserve = Reservation(request_id=rid, robots=[robot])
    release = Release(request_id=rid, robots=[robot])
    go = Assign(request_id=rid, location=[0.0, 0.0], capabilities=["kicker"])
    dispatch = Dispatch(robot=robot, command=go)
    c = session_as(b, certs, "cloud-c")
    try:
        # As cloud-a: on the keys that name cloud-a, cloud-b's router drops it all.
        for name, message in [
            ("reserve", reserve),
            ("confirm", reserve),
            ("release", release),
            ("cancel", release),
            ("dispatch", dispatch),
            ("loans", LoanQuery()),
        ]:
            assert send(c, keys.command("cloud-b", "cloud-a", name), message) == [], name
        # As itself, naming cloud-a's request and robot: cloud-b refuses and logs it.
        [taken] = send(c, keys.command("cloud-b", "cloud-c", "reserve"), reserve)
        assert taken["taken"] == [robot]
        [confirmed] = send(c, keys.command("cloud-b", "cloud-c", "confirm"), reserve)
        assert confirmed["taken"] == [robot] and "no live lease" in confirmed["error"]
        for name in ("release", "cancel"):
            [done] = send(c, keys.command("cloud-b", "cloud-c", name), release)
            assert done["ok"] is False and "cloud-c holds no loan" in done["error"], done
        [ack] = send(c, keys.command("cloud-b", "cloud-c", "dispatch"), dispatch)
        assert ack["ok"] is False and "not lent to request" in ack["error"]
        c_zid = str(c.zid())
    finally:
        c.close()  # type: ignore[no-untyped-call]
    # The six commands as cloud-a: each a refusal of cloud-b's router, logged and counted.
    wait_until(
        lambda: b.router_refusals().get(("cloud-c", "query"), 0.0) - before >= 6,
        10,
        "cloud-b to count cloud-c's commands as cloud-a",
    )
    said = [line for line in log_of(b).splitlines() if f"session {c_zid}" in line]
    for name in ("reserve", "confirm", "release", "cancel", "dispatch", "loans"):
        key = keys.command("cloud-b", "cloud-a", name)
        assert any(f"refused a query on '{key}' from cloud-c" in line for line in said), name
    refusals = [line for line in log_of(b).splitlines() if "refused a" in line]
    for what in ("confirm", "release", "cancel", "dispatch"):
        assert any(
            f"refused a {what} from cloud-c for request {rid}: {robot} is lent to cloud-a" in line
            for line in refusals
        ), (what, refusals)
    # cloud-a's work is untouched: the same robot still works for it, unstopped.
    with a.client() as client:
        now = client.get(f"/v1/requests/{rid}").json()
        assert now["state"] == "underway", now
        assert [x["robot"] for x in now["coalition"]] == [robot]
        assert not any("failed" in (h["detail"] or "") for h in now["history"]), now["history"]
        with b.client() as home:
            lent = {r["id"]: r for r in home.get("/v1/robots").json()}[robot]
        # At its home it is still busy; which request it works for, cloud-b's own
        # applications are not told (/v1/robots shows that only to the owner).
        assert lent["status"] == "busy" and lent["request"] is None, lent
        # cloud-a's own cancel reaches it: the robot is cloud-b's again.
        assert client.post(f"/v1/requests/{rid}/cancel").json()["state"] == "canceled"

    def free() -> bool:
        with b.client() as home:
            state = {r["id"]: r for r in home.get("/v1/robots").json()}[robot]
        return state["request"] is None and state["status"] == "idle"

    wait_until(free, 10, f"{robot} to be free at cloud-b")


def test_a_robot_certificate_sends_no_cloud_command(federation: tuple[list[Cloud], Path]) -> None:
    (_, b, _), certs = federation
    with b.client() as client:
        idle = [r["id"] for r in client.get("/v1/robots").json() if r["status"] == "idle"]
    reserve = Reservation(request_id="req-robots", robots=idle[:1])
    robots = session_as(b, certs, "cloud-b-robots")
    try:
        for sender in ("cloud-b-robots", "cloud-a", "cloud-b", "cloud-c"):
            for name in ("reserve", "confirm"):
                assert send(robots, keys.command("cloud-b", sender, name), reserve) == []
    finally:
        robots.close()  # type: ignore[no-untyped-call]
    with b.client() as client:
        now = {r["id"]: r for r in client.get("/v1/robots").json()}
    assert now[idle[0]]["status"] == "idle" and now[idle[0]]["request"] is None


def test_a_confirm_without_a_lease_is_refused(federation: tuple[list[Cloud], Path]) -> None:
    (_, b, _), certs = federation
    with b.client() as client:
        idle = [r["id"] for r in client.get("/v1/robots").json() if r["status"] == "idle"]
    c = session_as(b, certs, "cloud-c")
    try:
        confirm = Reservation(request_id="req-never-reserved", robots=idle[:1])
        [reply] = send(c, keys.command("cloud-b", "cloud-c", "confirm"), confirm)
    finally:
        c.close()  # type: ignore[no-untyped-call]
    assert reply["taken"] == idle[:1] and "no live lease" in reply["error"]
    with b.client() as client:
        now = {r["id"]: r for r in client.get("/v1/robots").json()}
    assert now[idle[0]]["status"] == "idle" and now[idle[0]]["request"] is None


def test_a_robot_certificate_fabricates_no_cloud(federation: tuple[list[Cloud], Path]) -> None:
    """The issue's first attack: cloud-b's robots' certificate at cloud-a's router declares
    cloud-zzz and claims cloud-b, with answers on their keys. cloud-a's router drops it all."""
    (a, _, _), certs = federation
    robots = session_as(a, certs, "cloud-b-robots")
    zid = str(robots.zid())
    zzz = '{"cloud": "cloud-zzz", "robots": 3, "idle": 3}'
    over = '{"requests": [{"request_id": "x", "known": false}]}'
    kept: list[Any] = [
        robots.liveliness().declare_token(keys.cloud_token("cloud-zzz", zid)),
        robots.liveliness().declare_token(keys.cloud_token("cloud-b", zid)),
        robots.declare_queryable(
            "robocloud/cloud-zzz/*", lambda query: query.reply(query.key_expr, zzz)
        ),
        robots.declare_queryable(
            "robocloud/cloud-b/status", lambda query: query.reply(query.key_expr, over)
        ),
    ]
    try:
        # An answer to a question it may ask: its link is up, its declarations passed before.
        wait_until(
            lambda: [r for r in robots.get("robocloud/cloud-a/info", timeout=1.0) if r.ok],
            10,
            "cloud-a to answer the robot's question",
        )
        with a.client() as client:
            clouds = [c["cloud"] for c in client.get("/v1/clouds").json()]
        assert clouds == ["cloud-a", "cloud-b", "cloud-c"]
    finally:
        for each in kept:
            each.undeclare()
        robots.close()  # type: ignore[no-untyped-call]
    # Each refusal is a line of cloud-a's log and a count of its metrics.
    wait_until(
        lambda: {
            message: n for (party, message), n in a.router_refusals().items()
            if party == "cloud-b-robots"
        } == {"liveliness_token": 2.0, "declare_queryable": 2.0},
        10,
        "cloud-a to count the refusals",
    )
    said = [line for line in log_of(a).splitlines() if "router refused" in line]
    for refused in (
        f"liveliness_token on '{keys.cloud_token('cloud-zzz', zid)}'",
        f"liveliness_token on '{keys.cloud_token('cloud-b', zid)}'",
        "declare_queryable on 'robocloud/cloud-zzz/*'",
        "declare_queryable on 'robocloud/cloud-b/status'",
    ):
        assert any(refused in line and "cloud-b-robots" in line for line in said), refused
    assert all("cloud-zzz" not in line for line in log_of(a).splitlines() if line not in said)


def test_a_member_cloud_answers_for_no_other(federation: tuple[list[Cloud], Path]) -> None:
    """The issue's second and third attacks with cloud-c's certificate at cloud-a's router:
    answers to cloud-a's status question for cloud-b ("request over", which ended other
    clouds' loans) and to its reserve and confirm commands. cloud-a's router refuses the
    queryables, each refusal a line of its log and a count; cloud-a's request, served by
    cloud-b's robot, goes on."""
    (a, b, _), certs = federation
    rid, robot = start_far_request(a, [1900.0, 100.0])
    before = a.router_refusals().get(("cloud-c", "declare_queryable"), 0.0)
    over = json.dumps({"requests": [{"request_id": rid, "known": False}]})
    forged = json.dumps({"taken": [], "error": "forged: nothing to lend"})
    c = session_as(a, certs, "cloud-c")
    zid = str(c.zid())
    answers = [
        c.declare_queryable("robocloud/cloud-b/status", lambda q: q.reply(q.key_expr, over)),
        c.declare_queryable("robocloud/*/from/cloud-a/*", lambda q: q.reply(q.key_expr, forged)),
        c.declare_queryable(
            keys.command("cloud-b", "cloud-a", "confirm"), lambda q: q.reply(q.key_expr, forged)
        ),
    ]
    try:
        wait_until(
            lambda: a.router_refusals().get(("cloud-c", "declare_queryable"), 0.0) - before >= 3,
            10,
            "cloud-a to count cloud-c's queryables",
        )
        # Asked as cloud-a asks (its own certificate, every queryable), cloud-b's status
        # and commands are answered by cloud-b's session alone, never by cloud-c's.
        tool = session_as(a, certs, "cloud-a")
        try:
            for key in ("robocloud/cloud-b/status", keys.command("cloud-b", "cloud-a", "confirm")):
                answered = repliers(tool, key, "{}")
                assert answered and zid not in answered, (key, answered)
        finally:
            tool.close()  # type: ignore[no-untyped-call]
        with a.client() as client:
            now = client.get(f"/v1/requests/{rid}").json()
        assert now["state"] == "underway", now
        with b.client() as home:
            lent = {r["id"]: r for r in home.get("/v1/robots").json()}[robot]
        assert lent["status"] == "busy", lent
    finally:
        for each in answers:
            each.undeclare()
        c.close()  # type: ignore[no-untyped-call]
    said = [line for line in log_of(a).splitlines() if f"session {zid}" in line]
    for key in (
        "robocloud/cloud-b/status",
        "robocloud/*/from/cloud-a/*",
        keys.command("cloud-b", "cloud-a", "confirm"),
    ):
        assert any(
            f"refused a declare_queryable on '{key}' from cloud-c" in line for line in said
        ), key
    with a.client() as client:
        assert client.post(f"/v1/requests/{rid}/cancel").json()["state"] == "canceled"


def test_a_member_cloud_cannot_lease_a_whole_fleet(federation: tuple[list[Cloud], Path]) -> None:
    """The issue's fifth attack with cloud-c's certificate at cloud-b's router (cloud-b
    trusts cloud-c): every robot of cloud-b, busy and charging ones included, for a day.
    Refused whole by the lending bounds, with a sentence; logged and counted."""
    (_, b, _), certs = federation

    def refused() -> float:
        with b.client() as client:
            text = client.get("/metrics").text
        found = [
            float(line.rsplit(" ", 1)[1])
            for line in text.splitlines()
            if line.startswith('robocloud_reservations_refused_total{origin="cloud-c"}')
        ]
        return found[0] if found else 0.0

    before = refused()
    with b.client() as client:
        fleet = [r["id"] for r in client.get("/v1/robots").json()]
    assert len(fleet) == ROBOTS
    everything = Reservation(request_id="req-everything", robots=fleet, lease_seconds=86400)
    c = session_as(b, certs, "cloud-c")
    try:
        [reply] = send(c, keys.command("cloud-b", "cloud-c", "reserve"), everything)
        [loans] = send(c, keys.command("cloud-b", "cloud-c", "loans"), LoanQuery())
    finally:
        c.close()  # type: ignore[no-untyped-call]
    assert loans["held"] == 0, loans  # cloud-b lent cloud-c nothing
    assert reply["taken"] == fleet, reply
    # Not idle or low on battery (the roster starts some busy and charging), or more than
    # cloud-c's share of the fleet (half): whichever bound the home checks first.
    assert (
        "only idle robots with at least 20% of battery are lent" in reply["error"]
        or "lends one cloud at most 50% of its robots (10)" in reply["error"]
    ), reply
    wait_until(lambda: refused() >= before + 1, 10, "cloud-b to count the refusal")
    assert "refused a reserve from cloud-c" in log_of(b)


def test_an_origin_that_disappears_loses_its_loans_and_learns_it_back(
    federation: tuple[list[Cloud], Path],
) -> None:
    (a, b, _), certs = federation
    rid, robot = start_far_request(a, [1950.0, 1950.0])
    tool = OverlaySecurity(
        ca=certs / "ca.pem", cert=certs / "cloud-b.pem", key=certs / "cloud-b.key"
    )
    a.kill_iaas()
    b.fault(
        robot, "silent", tool
    )  # it drives on, unheard: for cloud-b it no longer works for cloud-a
    try:
        ended = f"ended the loan of {robot} to cloud-a's request {rid}: cloud-a was unreachable"
        started = time.monotonic()
        wait_until(lambda: ended in log_of(b), 30, "cloud-b to end the loan of the silent robot")
        # Silent for 2.5 s (offline), then the 1 s deadline, give or take a reconciliation.
        assert time.monotonic() - started < 15
        with b.client() as client:
            held = {r["id"]: r["request"] for r in client.get("/v1/robots").json()}
        assert held[robot] is None
        a.start_iaas()
        with a.client() as client:
            told = wait_until(
                lambda: [
                    h["detail"]
                    for h in client.get(f"/v1/requests/{rid}").json()["history"]
                    if f"cloud-b ended the loan of robot {robot}" in (h["detail"] or "")
                ],
                30,
                "cloud-a, back, to learn that cloud-b ended its loan",
            )
        assert len(told) == 1 and f"cloud-a was unreachable for {DEADLINE:g} s" in told[0]
        back = f"cloud-a is back; 1 of its loans ended while it was away ({robot})"
        wait_until(lambda: back in log_of(b), 10, "cloud-b to note that cloud-a is back")
    finally:
        b.fault(robot, "recover", tool)
