"""Replies checked by the asker, written as the attacker would: a Zenoh client on cloud-a's
router answering for cloud-b, and declaring a cloud that does not exist.

Real Zenoh routers on loopback, without TLS: the asker's check holds whatever
the router lets through (with mutual TLS the router's access control also
stops these declarations: tests/system/test_secure_federation.py).
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator
from dataclasses import dataclass

import pytest
import zenoh
from federation_testing import free_endpoint
from test_overlay_security import Desk

from robocloud.federation import keys
from robocloud.federation.messages import (
    IdleQuery,
    IdleReply,
    LoanQuery,
    RequestStatus,
    Reservation,
    StatusQuery,
    StatusReply,
)
from robocloud.federation.overlay import Unreachable, ZenohOverlay
from robocloud.fleet import open_client, open_router
from robocloud.iaas.metrics import IaasMetrics
from waiting import wait_until


@dataclass
class TrustingDesk(Desk):
    """A desk whose cloud trusts only the clouds named; its requests are all live."""

    trusted: tuple[str, ...] = ()

    def trusts(self, cloud: str) -> bool:
        return cloud == self.cloud or cloud in self.trusted

    def status(self, query: StatusQuery) -> StatusReply:
        return StatusReply(
            requests=[
                RequestStatus(request_id=r, known=True, final=False) for r in query.request_ids
            ]
        )


@dataclass
class Clouds:
    a: ZenohOverlay
    b: ZenohOverlay
    a_endpoint: str
    forger: zenoh.Session  # a client of cloud-a's router


@pytest.fixture
def clouds() -> Iterator[Clouds]:
    a_endpoint = free_endpoint()
    a_session = open_router([a_endpoint])
    b_session = open_router([free_endpoint()], [a_endpoint])
    a = ZenohOverlay(a_session, "cloud-a", TrustingDesk("cloud-a", trusted=("cloud-b",)))
    b = ZenohOverlay(b_session, "cloud-b", TrustingDesk("cloud-b", trusted=("cloud-a",)))
    forger = open_client([a_endpoint])
    wait_until(lambda: a.clouds() == ["cloud-a", "cloud-b"], what="cloud-a to see cloud-b")
    try:
        yield Clouds(a, b, a_endpoint, forger)
    finally:
        forger.close()  # type: ignore[no-untyped-call]
        a.close()
        with contextlib.suppress(zenoh.ZError):  # a test may have closed it already
            b.close()
        a_session.close()  # type: ignore[no-untyped-call]
        b_session.close()  # type: ignore[no-untyped-call]


def forge(session: zenoh.Session, key: str, payload: str) -> zenoh.Queryable[None]:
    return session.declare_queryable(key, lambda query: query.reply(query.key_expr, payload))


def test_a_forged_status_answer_does_not_end_loans(
    clouds: Clouds, caplog: pytest.LogCaptureFixture
) -> None:
    """The attacker answers cloud-b's status question: 'request r-1 is over'."""
    over = StatusReply(requests=[RequestStatus(request_id="r-1", known=False)])
    forged = forge(clouds.forger, keys.question("cloud-b", "status"), over.model_dump_json())
    query = StatusQuery(home="cloud-a", request_ids=["r-1"])
    caplog.set_level(logging.WARNING, "robocloud.federation.presence")
    # Until the forger's queryable is known at cloud-a's router, its reply does
    # not come; each answer meanwhile must still be cloud-b's own.
    wait_until(
        lambda: clouds.a.status("cloud-b", query) and clouds.a.presence.refusals(),
        what="the forged reply to reach cloud-a",
    )
    for _ in range(5):
        reply = clouds.a.status("cloud-b", query)
        assert reply.requests[0].known is True  # cloud-b's own answer, every time
    # Counted when they came before cloud-b's (the asker stops at the real one).
    assert clouds.a.presence.refusals()[("status", "forged")] >= 1
    metrics = IaasMetrics()
    metrics.observe_refusals(clouds.a.presence.refusals, dict)
    scrape = metrics.exposition(None)[0].decode()
    assert 'robocloud_overlay_replies_dropped_total{asked="status",why="forged"}' in scrape
    assert "dropped a forged reply to the status: it claims to be cloud-b's" in caplog.text
    forged.undeclare()  # type: ignore[no-untyped-call]


def test_forged_reserve_and_confirm_answers_are_dropped(clouds: Clouds) -> None:
    """The attacker answers cloud-b's command keys first, with a refusal."""
    refusal = '{"taken": ["b-1"], "error": "forged: taken"}'
    forged = forge(clouds.forger, "robocloud/cloud-b/from/*/*", refusal)
    reservation = Reservation(request_id="r-1", robots=["b-1"])
    wait_until(
        lambda: clouds.a.loans("cloud-b", LoanQuery()) and clouds.a.presence.refusals(),
        what="the forged reply to reach cloud-a",
    )
    for _ in range(3):
        assert clouds.a.reserve("cloud-b", reservation).taken == []
        assert clouds.a.confirm("cloud-b", reservation).error is None
    refused = clouds.a.presence.refusals()
    assert refused[("loans", "forged")] >= 1
    forged.undeclare()  # type: ignore[no-untyped-call]
    # cloud-b gone, the forger alone answers: cloud-a hears nobody.
    clouds.b.close()
    forged = forge(clouds.forger, "robocloud/cloud-b/from/*/*", refusal)
    wait_until(lambda: clouds.a.clouds() == ["cloud-a"], what="cloud-a to see cloud-b go")
    with pytest.raises(Unreachable, match="not a cloud cloud-a trusts"):
        clouds.a.reserve("cloud-b", reservation)
    forged.undeclare()  # type: ignore[no-untyped-call]


def test_a_forged_idle_answer_offers_no_robot(clouds: Clouds) -> None:
    robot = {
        "id": "b-666", "cloud": "cloud-b", "position": [0.0, 0.0],
        "speed": 1000.0, "battery": 100.0, "status": "idle", "travel_cost_per_m": 0.0,
        "capabilities": {"grabber": {"kind": "actuating", "time": 0.0, "cost": 0.0}},
    }  # fmt: skip
    offer = IdleReply.model_validate({"cloud": "cloud-b", "robots": [robot]})
    forged = forge(clouds.forger, keys.question("cloud-b", "idle"), offer.model_dump_json())
    wait_until(
        lambda: clouds.a.gather_idle(IdleQuery(origin="cloud-a")) and clouds.a.presence.refusals(),
        what="the forged idle reply to reach cloud-a",
    )
    gathered = clouds.a.gather_idle(IdleQuery(origin="cloud-a"))
    assert [r.id for r in gathered.replies["cloud-b"].robots] == []  # cloud-b's real answer
    forged.undeclare()  # type: ignore[no-untyped-call]


def test_a_robot_cannot_fabricate_a_cloud(clouds: Clouds, caplog: pytest.LogCaptureFixture) -> None:
    """A presence token of cloud-zzz and its answers: cloud-a, trusting cloud-b only, ignores it."""
    caplog.set_level(logging.INFO, "robocloud.federation.presence")
    zid = str(clouds.forger.zid())
    token = clouds.forger.liveliness().declare_token(keys.cloud_token("cloud-zzz", zid))
    info = '{"cloud": "cloud-zzz", "robots": 3, "idle": 3}'
    answers = [
        forge(clouds.forger, keys.question("cloud-zzz", "info"), info),
        forge(
            clouds.forger, keys.question("cloud-zzz", "idle"), '{"cloud":"cloud-zzz","robots":[]}'
        ),
    ]
    # Both clouds of this process log what they hear: wait for cloud-a's own line.
    untrusted = "cloud-a does not trust it: it is neither asked nor answered"
    wait_until(
        lambda: any("cloud-zzz is present" in m and untrusted in m for m in caplog.messages),
        what="cloud-a to hear of cloud-zzz and not trust it",
    )
    assert clouds.a.clouds() == ["cloud-a", "cloud-b"]
    assert [i.cloud for i in clouds.a.infos()] == ["cloud-a", "cloud-b"]
    assert sorted(clouds.a.gather_idle(IdleQuery(origin="cloud-a")).replies) == ["cloud-b"]
    with pytest.raises(Unreachable, match="not a cloud cloud-a trusts"):
        clouds.a.reserve("cloud-zzz", Reservation(request_id="r-1", robots=["z-1"]))
    # Claiming cloud-b beside the real one: nobody is believed for it until one goes.
    claim = clouds.forger.liveliness().declare_token(keys.cloud_token("cloud-b", zid))
    wait_until(
        lambda: clouds.a.clouds() == ["cloud-a"],
        what="cloud-b to be left out while disputed",
    )
    assert "2 sessions declare the presence of cloud-b" in caplog.text
    claim.undeclare()  # type: ignore[no-untyped-call]
    wait_until(lambda: clouds.a.clouds() == ["cloud-a", "cloud-b"], what="cloud-b to be back")
    for kept in (token, *answers):
        kept.undeclare()  # type: ignore[no-untyped-call]
