"""The idle robots a home sends for another cloud's selection: written fast, read fast, same rules.

The home writes each robot's JSON once and keeps it while the robot says the
same; the asker decodes the reply with msgspec (``decode_idle_reply``) under
``Robot``'s limits. Both must agree with the pydantic models they replace.
"""

from __future__ import annotations

import json

import pytest
from federation_testing import clouds, robot

from robocloud.domain import Robot, Task
from robocloud.federation.home import Home
from robocloud.federation.messages import IdleQuery, IdleReply, decode_idle_reply
from robocloud.fleet import MemoryRobotLink
from robocloud.storage import MemoryRequestStore

QUERY = IdleQuery(origin="cloud-a", capabilities=["grabber"])
TASK = Task.model_validate(
    {
        "location": [0.0, 0.0],
        "actuating": {"grabber": 1},
        "max_robots": 3,
        "max_cost": 100.0,
        "max_time": 300.0,
    }
)


def home_with(robots: list[Robot]) -> tuple[Home, MemoryRobotLink]:
    link = MemoryRobotLink("cloud-b", robots)
    return Home("cloud-b", MemoryRequestStore(), link), link


def test_the_reply_is_the_idle_reply_of_its_robots() -> None:
    robots = [robot("cloud-b", i, 10.0 * i) for i in range(5)]
    home, link = home_with(robots)
    link.put(robots[2].model_copy(update={"status": "busy"}))
    home.store.lend("cloud-c", "req-c", ["b-3"], 30.0)
    reply = IdleReply.model_validate_json(home.idle_robots(QUERY))
    assert reply.cloud == "cloud-b"
    assert [r.id for r in reply.robots] == ["b-0", "b-1", "b-4"]
    assert reply.robots[1] == robots[1]
    decoded = decode_idle_reply(home.idle_robots(QUERY))
    assert [(r.id, r.position, r.battery) for r in decoded.robots] == [
        (r.id, tuple(r.position), r.battery) for r in reply.robots
    ]
    # The query's filter: a capability none has, a battery none reaches.
    unknown = IdleQuery(origin="cloud-a", capabilities=["x"])
    assert decode_idle_reply(home.idle_robots(unknown)).robots == []
    assert (
        decode_idle_reply(home.idle_robots(IdleQuery(origin="cloud-a", min_battery=95.0))).robots
        == []
    )
    # Its own cloud's question gets no robot (they are already in its view).
    assert decode_idle_reply(home.idle_robots(IdleQuery(origin="cloud-b"))).robots == []


def test_a_robot_that_changed_is_written_again() -> None:
    home, link = home_with([robot("cloud-b", 0)])
    before = decode_idle_reply(home.idle_robots(QUERY)).robots[0]
    link.put(robot("cloud-b", 0).model_copy(update={"position": [55.0, 5.0]}))
    after = decode_idle_reply(home.idle_robots(QUERY)).robots[0]
    assert before.position == (10.0, 0.0)
    assert after.position == (55.0, 5.0)


@pytest.mark.parametrize(
    ("change", "words"),
    [
        (lambda r: r.update(battery=101.0), "battery"),
        (lambda r: r.update(speed=0.0), "speed"),
        (lambda r: r.update(position=[1e8, 0.0]), "position"),
        (lambda r: r.update(status="sleeping"), "status"),
        (lambda r: r.update(extra=1), "extra"),
        (lambda r: r.update(id="b-\u0007"), "id"),
        (lambda r: r.update(id="b-\u007f"), "id"),
    ],
)
def test_a_reply_that_breaks_a_robots_rule_is_refused(change: object, words: str) -> None:
    data = robot("cloud-b", 0).model_dump(mode="json")
    change(data)  # type: ignore[operator]
    payload = json.dumps({"cloud": "cloud-b", "robots": [data]}).encode()
    with pytest.raises(ValueError, match=words):
        decode_idle_reply(payload)
    with pytest.raises(ValueError):
        IdleReply.model_validate_json(payload)


def test_unknown_reply_fields_are_ignored_and_oversized_replies_refused() -> None:
    data = robot("cloud-b", 0).model_dump(mode="json")
    reply = decode_idle_reply(json.dumps({"cloud": "cloud-b", "robots": [data], "v": 2}).encode())
    assert [r.id for r in reply.robots] == ["b-0"]
    with pytest.raises(ValueError, match="length"):
        decode_idle_reply(json.dumps({"cloud": "cloud-b", "robots": [data] * 1001}).encode())
    with pytest.raises(ValueError):
        decode_idle_reply(b"{not json")


def test_robots_a_home_names_as_another_clouds_are_left_out() -> None:
    _, c = clouds(("cloud-a", "cloud-b", "cloud-c"), robots=1)
    c["cloud-b"].link.put(robot("cloud-c", 7))  # cloud-b sends a robot it says is cloud-c's
    seen = c["cloud-a"].view.remote_robots(TASK, exclude=set())
    assert sorted((r.id, r.cloud) for r in seen.robots) == [("b-0", "cloud-b"), ("c-0", "cloud-c")]
