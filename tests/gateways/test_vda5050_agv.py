"""The gateway without a broker: its messages against the official schemas; an AGV as a robot."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from vda5050_testing import factsheet, schema_errors, vda_state

from robocloud.errors import InvalidInput, NotFound
from robocloud.fleet.messages import Assign
from robocloud.gateways.vda5050 import messages as vda
from robocloud.gateways.vda5050.agv import Agv, BadMessage, Stale, Timing, request_of
from robocloud.gateways.vda5050.capabilities import GatewayCapabilities, load_capabilities
from robocloud.gateways.vda5050.gateway import robot_id

CAPS = GatewayCapabilities.model_validate(
    {
        "capabilities": {
            "lift": {"kind": "actuating", "time": 4.0, "cost": 2.0, "action": "pick",
                     "parameters": [{"key": "height", "value": 0.5}]},
            "scan": {"kind": "sensing", "time": 1.0, "cost": 1.0, "action": "detectObject"},
            "weld": {"kind": "actuating", "time": 9.0, "cost": 9.0, "action": "weld"},
        },
        "travel_cost_per_m": 0.1,
    }
)  # fmt: skip
NAME = vda.AgvName("acme", "agv-1")


def feed(agv: Agv, state: vda.VdaState, now: float) -> None:
    """The AGV's state at ``now`` (monotonic and unix time alike here)."""
    agv.on_state(state, now, now)


def agv_with(**state: object) -> Agv:
    agv = Agv(NAME, "acme.agv-1")
    agv.on_connection("ONLINE", 0.0)
    agv.on_factsheet(vda.Factsheet.model_validate(factsheet(["pick", "detectObject"])), 0.0, 0.0)
    feed(agv, vda.VdaState.model_validate(vda_state(**state)), 0.0)
    return agv


def test_the_messages_the_gateway_writes_are_valid_vda5050() -> None:
    headers = vda.Headers()
    actions = [
        vda.NodeAction("pick", "o-1-lift", "SOFT", [{"key": "height", "value": 0.5}]),
        vda.NodeAction("detectObject", "o-1-scan", "SOFT"),
    ]
    order = vda.order(headers.header(NAME, "order", 1767225600.0), "req-x.1", (10.0, 5.0),
                      (40.0, -2.5), "floor-1", actions)  # fmt: skip
    assert schema_errors("order", order) == []
    assert [n["sequenceId"] for n in order["nodes"]] == [0, 2]
    assert order["edges"][0]["sequenceId"] == 1
    assert order["nodes"][1]["actions"][0]["actionParameters"] == [{"key": "height", "value": 0.5}]
    cancel = vda.cancel_order(headers.header(NAME, "instantActions", 1767225601.0), "c-1")
    assert schema_errors("instantActions", cancel) == []
    assert cancel["actions"][0]["actionType"] == "cancelOrder"
    request = vda.factsheet_request(headers.header(NAME, "instantActions", 1767225602.5), "f-1")
    assert schema_errors("instantActions", request) == []
    assert request["headerId"] == 1  # counted per topic
    assert request["timestamp"] == "2026-01-01T00:00:02.50Z"
    # The checker itself refuses what is wrong.
    assert schema_errors("order", {**order, "orderUpdateId": -1})
    assert schema_errors("instantActions", {**cancel, "actions": [{"actionType": "x"}]})


def test_an_agv_reads_as_a_robot() -> None:
    agv = agv_with()
    state = agv.state("cloud-a", CAPS, 1.0, 1767225600.0)
    assert state is not None
    assert state.id == "acme.agv-1" and state.cloud == "cloud-a"
    assert state.kind == "carrier-x"
    assert state.position == [10.0, 5.0]
    assert state.battery == 80.0
    assert state.speed == 2.0
    assert state.status == "idle"
    assert state.travel_cost_per_m == 0.1
    assert sorted(state.capabilities) == ["lift", "scan"]  # weld: the factsheet has no "weld"
    assert state.capabilities["lift"].time == 4.0


@pytest.mark.parametrize(
    ("changes", "status"),
    [
        ({"nodeStates": [{"nodeId": "n", "sequenceId": 2, "released": True}]}, "busy"),
        ({"actionStates": [{"actionId": "a", "actionStatus": "RUNNING"}]}, "busy"),
        ({"batteryState": {"batteryCharge": 40.0, "charging": True}}, "charging"),
        ({"operatingMode": "MANUAL"}, "offline"),
        ({"errors": [{"errorType": "bumper", "errorLevel": "FATAL"}]}, "offline"),
        ({"errors": [{"errorType": "slow", "errorLevel": "WARNING"}]}, "idle"),
    ],
)
def test_the_status_follows_the_vda_state(changes: dict[str, object], status: str) -> None:
    assert agv_with(**changes).status(1.0) == status


def test_a_broken_connection_or_a_silent_agv_is_offline() -> None:
    agv = agv_with()
    # The factsheet gives no defaultStateInterval: 3 of the default 10 s.
    assert agv.silent_after() == 30.0
    assert agv.status(29.0) == "idle"
    assert agv.status(31.0) == "offline"  # its last will or not
    agv.on_connection("CONNECTIONBROKEN", 1.0)
    assert agv.status(1.0) == "offline"


def test_bad_values_are_refused_with_a_sentence() -> None:
    agv = agv_with()
    with pytest.raises(BadMessage, match="batteryCharge is 120, not a percent"):
        feed(agv, vda.VdaState.model_validate(vda_state(batteryState={
            "batteryCharge": 120.0, "charging": False})), 1.0)  # fmt: skip
    with pytest.raises(BadMessage, match="out of range"):
        agv.on_visualization(vda.AgvPosition(x=1e9, y=0.0), 1.0, 1.0)


def test_an_order_is_followed_to_done() -> None:
    agv = agv_with()
    command = Assign(request_id="req-x", location=[30.0, 5.0], capabilities=["lift", "scan"])
    assert agv.refuse(command, CAPS, 1.0) is None
    actions = agv.take(command, CAPS, 1.0)
    job = agv.job
    assert job is not None and job.order_id == "req-x.1"
    assert [a.action_type for a in actions] == ["pick", "detectObject"]
    assert job.travel == 10.0  # 20 m at 2 m/s
    assert job.work == 4.0  # parallel: the longest
    end = {"nodeId": "req-x.1-end", "sequenceId": 2, "released": True}
    waiting = [{"actionId": a.action_id, "actionStatus": "WAITING"} for a in actions]
    feed(agv, vda.VdaState.model_validate(vda_state(
        orderId="req-x.1", nodeStates=[end], actionStates=waiting,
        agvPosition={"x": 20.0, "y": 5.0, "theta": 0, "mapId": "floor-1",
                     "positionInitialized": True})), 2.0)  # fmt: skip
    assert job.accepted and job.phase == "travel"
    assert job.progress == pytest.approx(10 / 14 * 0.5)
    running = [{**w, "actionStatus": "RUNNING"} for w in waiting]
    feed(agv, vda.VdaState.model_validate(vda_state(
        orderId="req-x.1", actionStates=running, agvPosition={
            "x": 30.0, "y": 5.0, "theta": 0, "mapId": "floor-1",
            "positionInitialized": True})), 3.0)  # fmt: skip
    assert job.phase == "work"
    assert agv.status(3.0) == "busy"
    finished = [{**w, "actionStatus": "FINISHED"} for w in waiting]
    feed(agv, vda.VdaState.model_validate(vda_state(
        orderId="req-x.1", actionStates=finished)), 7.0)  # fmt: skip
    assert agv.job is None
    state = agv.state("cloud-a", CAPS, 7.5, 1.0)
    assert state is not None and state.task is not None and state.task.phase == "done"
    assert state.last_task is not None and state.last_task.request_id == "req-x"
    assert state.status == "idle"
    later = agv.state("cloud-a", CAPS, 11.0, 2.0)  # past the 3 s a finished task stays
    assert later is not None and later.task is None and later.last_task is not None


@pytest.mark.parametrize(
    ("changes", "why"),
    [
        ({"actionStates": [{"actionId": "req-x.1-lift", "actionStatus": "FAILED",
                            "resultDescription": "nothing to pick"}]},
         "its action req-x.1-lift failed: nothing to pick"),
        ({"errors": [{"errorType": "orderError", "errorLevel": "WARNING",
                      "errorReferences": [{"referenceKey": "orderId",
                                           "referenceValue": "req-x.1"}]}]},
         "the AGV reports orderError (warning)"),
        ({"orderId": "someone-else"}, "the AGV dropped the order for 'someone-else'"),
    ],
)  # fmt: skip
def test_an_order_fails_as_the_agv_says(changes: dict[str, object], why: str) -> None:
    agv = agv_with()
    agv.take(Assign(request_id="req-x", location=[30.0, 5.0], capabilities=["lift"]), CAPS, 1.0)
    accepted = vda_state(orderId="req-x.1", nodeStates=[
        {"nodeId": "req-x.1-end", "sequenceId": 2, "released": True}])  # fmt: skip
    if "orderId" in changes:
        feed(agv, vda.VdaState.model_validate(accepted), 2.0)
    later = {**accepted, **changes, "headerId": accepted["headerId"] + 1}
    feed(agv, vda.VdaState.model_validate(later), 3.0)
    assert agv.job is None
    assert agv.finished is not None and agv.finished.phase == "failed"
    assert agv.failure == why


def test_refusals_say_why() -> None:
    agv = agv_with()
    go = Assign(request_id="req-x", location=[30.0, 5.0], capabilities=["weld"])
    assert agv.refuse(go, CAPS, 1.0) == "AGV acme.agv-1 lacks the capability weld."
    low = agv_with(batteryState={"batteryCharge": 5.0, "charging": False})
    lift = go.model_copy(update={"capabilities": ["lift"]})
    assert "battery (5.0%) is below the 10% a task needs" in str(low.refuse(lift, CAPS, 1.0))
    agv.take(lift, CAPS, 1.0)
    other = lift.model_copy(update={"request_id": "req-y"})
    assert agv.refuse(other, CAPS, 1.0) == "AGV acme.agv-1 is busy with request req-x."
    assert agv.refuse(lift, CAPS, 1.0) is None  # the same request again


def test_robot_ids_and_topics() -> None:
    assert robot_id(vda.AgvName("acme", "agv-1")) == "acme.agv-1"
    assert robot_id(vda.AgvName("acme", "a$b")) is None
    assert vda.parse_topic("uagv/v2/acme/agv-1/state", "uagv", "v2") == (NAME, "state")
    assert vda.parse_topic("uagv/v1/acme/agv-1/state", "uagv", "v2") is None
    assert vda.parse_topic("uagv/v2/acme/state", "uagv", "v2") is None


def test_the_capabilities_file_is_checked(tmp_path: Path) -> None:
    good = tmp_path / "caps.json"
    good.write_text(json.dumps(CAPS.model_dump(mode="json")))
    assert load_capabilities(str(good)) == CAPS
    assert load_capabilities(None).capabilities == {}
    bad = tmp_path / "bad.json"
    bad.write_text(
        json.dumps(
            {"capabilities": {"lift": {"kind": "moving", "time": 1, "cost": 1, "action": "pick"}}}
        )
    )
    with pytest.raises(InvalidInput, match=r"bad.json: capabilities.lift.kind: input should be"):
        load_capabilities(str(bad))
    bad.write_text("{")
    with pytest.raises(InvalidInput, match="is not valid JSON"):
        load_capabilities(str(bad))
    with pytest.raises(NotFound, match="no such file"):
        load_capabilities(str(tmp_path / "none.json"))


def test_a_failed_task_whose_order_still_runs_is_still_cancelled() -> None:
    agv = agv_with()
    agv.take(Assign(request_id="req-x", location=[30.0, 5.0], capabilities=["lift"]), CAPS, 1.0)
    end = {"nodeId": "req-x.1-end", "sequenceId": 2, "released": True}
    feed(agv, vda.VdaState.model_validate(vda_state(orderId="req-x.1", nodeStates=[end], errors=[
        {"errorType": "bumper", "errorLevel": "FATAL"}])), 2.0)  # fmt: skip
    assert agv.job is None and agv.failure == "the AGV reports bumper (fatal)"
    assert agv.still_running("req-x") == "req-x.1"  # it holds the order: cancelOrder is due
    assert agv.still_running("req-y") is None
    feed(agv, vda.VdaState.model_validate(vda_state(orderId="req-x.1")), 3.0)
    assert agv.still_running("req-x") is None  # nothing left of it


# -- the AGV's word, checked (issue 24) ---------------------------------------------------


def test_an_older_or_repeated_state_is_ignored_never_acted_on() -> None:
    agv = agv_with()
    agv.take(Assign(request_id="req-x", location=[30.0, 5.0], capabilities=["lift"]), CAPS, 1.0)
    end = {"nodeId": "req-x.1-end", "sequenceId": 2, "released": True}
    taken = vda_state(orderId="req-x.1", nodeStates=[end], timestamp="2026-11-29T23:00:40.00Z")
    feed(agv, vda.VdaState.model_validate(taken), 2.0)
    assert agv.job is not None and agv.job.accepted
    # A replay of an old state (lower headerId, older timestamp) would say "dropped the order".
    old = vda_state(headerId=0, timestamp="2026-11-29T23:00:30.00Z")
    with pytest.raises(Stale, match=r"headerId 0 of 2026-11-29T23:00:30\.00Z is not newer"):
        feed(agv, vda.VdaState.model_validate(old), 3.0)
    with pytest.raises(Stale):  # the same state again
        feed(agv, vda.VdaState.model_validate(taken), 3.0)
    # A greater headerId but a timestamp that went back: refused too.
    back = {**taken, "headerId": taken["headerId"] + 5, "timestamp": "2026-11-29T23:00:39.99Z"}
    with pytest.raises(Stale):
        feed(agv, vda.VdaState.model_validate(back), 3.0)
    assert agv.job is not None and agv.job.order_id == "req-x.1" and agv.failure is None
    # A new connection (the AGV restarted) counts its headers from 0 again.
    agv.on_connection("CONNECTIONBROKEN", 4.0)
    agv.on_connection("ONLINE", 5.0)
    feed(agv, vda.VdaState.model_validate(vda_state(headerId=0)), 5.0)
    assert agv.header_id == 0


def test_an_order_the_agv_never_shows_fails_with_a_reason_and_is_cancelled() -> None:
    agv = agv_with()
    agv.take(Assign(request_id="req-x", location=[30.0, 5.0], capabilities=["lift"]), CAPS, 1.0)
    feed(agv, vda.VdaState.model_validate(vda_state()), 2.0)  # states, but no order in them
    agv.tick(5.9)
    assert agv.job is not None  # 5 s after it was sent at 1.0: not yet
    # The right orderId with another orderUpdateId is not the order either.
    feed(agv, vda.VdaState.model_validate(vda_state(orderId="req-x.1", orderUpdateId=3)), 5.9)
    agv.tick(6.1)
    assert agv.job is None and agv.not_accepted == 1
    assert agv.cancels == [("req-x.1", "it never showed the order")]
    state = agv.state("cloud-a", CAPS, 6.1, 6.1)
    assert state is not None and state.task is not None and state.task.phase == "failed"
    assert state.task.reason == (
        "AGV acme.agv-1: the AGV did not show the order req-x.1 (orderUpdateId 0) in its "
        "state within 5 s."
    )


def test_a_silent_agv_is_offline_after_three_state_intervals_and_its_task_fails() -> None:
    agv = agv_with()
    agv.on_factsheet(vda.Factsheet.model_validate(
        factsheet(["pick"], state_interval=1.0)), 0.0, 0.0)  # fmt: skip
    assert agv.silent_after() == 3.0
    agv.take(Assign(request_id="req-x", location=[30.0, 5.0], capabilities=["lift"]), CAPS, 0.5)
    feed(agv, vda.VdaState.model_validate(vda_state(orderId="req-x.1", nodeStates=[
        {"nodeId": "req-x.1-end", "sequenceId": 2, "released": True}])), 1.0)  # fmt: skip
    state = agv.state("cloud-a", CAPS, 3.5, 1767225603.5)
    assert state is not None and state.status == "busy"
    assert state.sent_at == 1.0  # the AGV's last word, not the time of publishing
    agv.tick(4.1)
    assert agv.status(4.1) == "offline" and agv.job is None
    assert agv.finished is not None and agv.finished.reason is not None
    assert "silent for 3.1 s, over the 3 s allowed" in agv.finished.reason
    assert agv.cancels == [("req-x.1", "it went silent")]
    # The VDA 5050 bound: never more than 30 s, whatever the factsheet says.
    assert Timing().silent_after(60.0) == 30.0


def test_an_order_found_after_a_restart_is_adopted_then_cancelled_unless_assigned_again() -> None:
    end = {"nodeId": "req-x.4-end", "sequenceId": 2, "released": True}
    running = [{"actionId": "req-x.4-lift", "actionStatus": "WAITING"}]
    # The gateway restarted: this AGV is on an order of the gateway before.
    agv = agv_with(orderId="req-x.4", nodeStates=[end], actionStates=running)
    job = agv.job
    assert job is not None and job.adopted and not job.confirmed
    assert job.request_id == "req-x" and job.capabilities == ("lift",)
    assert agv.notes and "found on order req-x.4 of request req-x" in agv.notes[0]
    state = agv.state("cloud-a", CAPS, 1.0, 1.0)
    assert state is not None and state.task is not None and state.task.request_id == "req-x"
    agv.tick(5.1)
    assert agv.job is None
    assert agv.finished is not None and agv.finished.phase == "failed"
    assert agv.cancels == [
        ("req-x.4", "the IaaS did not assign request req-x to it since the gateway started")
    ]
    agv.tick(6.0)
    assert len(agv.cancels) == 1  # again at most every 2 s while the AGV keeps at it
    agv.tick(7.2)
    assert len(agv.cancels) == 2
    # The IaaS assigns it again within the grace: the order is kept, nothing cancelled.
    kept = agv_with(orderId="req-x.4", nodeStates=[end], actionStates=running)
    again = Assign(request_id="req-x", location=[30.0, 5.0], capabilities=["lift"])
    assert kept.refuse(again, CAPS, 2.0) is None
    kept.tick(9.0)
    assert kept.job is not None and kept.job.confirmed and kept.cancels == []
    # A new order for that request after it never reuses the id the AGV knows.
    kept.cancel()
    feed(kept, vda.VdaState.model_validate(vda_state(orderId="req-x.4")), 9.5)
    kept.take(again, CAPS, 10.0)
    assert kept.job is not None and kept.job.order_id == "req-x.5"


def test_an_order_of_another_form_is_left_alone_and_ended_jobs_are_cancelled() -> None:
    other = agv_with(orderId="wms-77", nodeStates=[
        {"nodeId": "n", "sequenceId": 2, "released": True}])  # fmt: skip
    other.tick(60.0)
    assert other.job is None and other.cancels == [] and other.status(1.0) == "busy"
    assert request_of("wms-77") is None and request_of("r.1.2") == "r.1"
    # A job the gateway sent that failed while the AGV keeps the order: cancelled at once.
    agv = agv_with()
    agv.take(Assign(request_id="req-x", location=[30.0, 5.0], capabilities=["lift"]), CAPS, 1.0)
    end = {"nodeId": "req-x.1-end", "sequenceId": 2, "released": True}
    feed(agv, vda.VdaState.model_validate(vda_state(orderId="req-x.1", nodeStates=[end], errors=[
        {"errorType": "bumper", "errorLevel": "FATAL"}])), 2.0)  # fmt: skip
    assert agv.cancels == [("req-x.1", "its robocloud task is over")]


def test_an_agv_remembers_only_its_newest_orders() -> None:
    agv = agv_with()
    go = Assign(request_id="req-x", location=[30.0, 5.0], capabilities=["lift"])
    for n in range(100):
        agv.take(go.model_copy(update={"request_id": f"req-{n}"}), CAPS, 1.0)
        agv.cancel()
    assert len(agv.sent_orders) == 64 and "req-99.100" in agv.sent_orders
    assert "req-0.1" not in agv.sent_orders
