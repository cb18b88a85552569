"""``GET /v1/robots`` is bounded: pages in bytes, what the listing keeps in robots (issue 25).

Robots that carry 100 capabilities of 128-character names are about 30 KB of
JSON each: one page of 5,000 of them was 45 MB. A page now stops at the robot
that takes it past ``PAGE_BYTES`` and its ``Link`` leads on from there; a walk
still lists every robot once. And a full listing of 100,000 robots kept every
robot's JSON (the IaaS went from 823 to 1,107 MB): now at most ``KEPT``.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient

from robocloud.domain import Robot
from robocloud.fleet import MemoryRobotLink
from robocloud.iaas import robot_list
from robocloud.iaas.app import create_app
from robocloud.iaas.config import Settings
from robocloud.iaas.robot_list import MAX_LIMIT, PAGE_BYTES, RobotJson, build_page
from robocloud.storage import MemoryRequestStore

A = {"Authorization": "Bearer key-a"}
HEAVY = 200  # robots of about 30 KB: 6 MB in all


def heavy_robot(i: int) -> Robot:
    names = {f"{c:03d}" + "c" * 125: {"kind": "sensing", "time": 1.0, "cost": 1.0}
             for c in range(100)}
    return Robot.model_validate(
        {
            "id": f"a-{i:04d}",
            "cloud": "cloud-a",
            "position": [float(i), 0.0],
            "speed": 1.0,
            "battery": 90.0,
            "status": "idle",
            "travel_cost_per_m": 0.1,
            "capabilities": names,
        }
    )


@pytest.fixture
def client() -> Iterator[TestClient]:
    link = MemoryRobotLink("cloud-a", [heavy_robot(i) for i in range(HEAVY)],
                           offline_after=3600.0)
    settings = Settings(cloud="cloud-a", api_keys={"key-a": "app-a"}, selection_workers=0)
    with TestClient(create_app(settings, store=MemoryRequestStore(), link=link)) as c:
        yield c


def test_a_page_stops_at_its_byte_budget_and_the_walk_goes_on(client: TestClient) -> None:
    path: str | None = f"/v1/robots?limit={MAX_LIMIT}"
    seen: list[str] = []
    sizes = []
    while path:
        answer = client.get(path, headers=A)
        assert answer.status_code == 200
        robots = answer.json()
        largest = max(len(r) for r in answer.content.split(b"},{"))
        assert len(answer.content) <= PAGE_BYTES + largest + 2
        sizes.append(len(answer.content))
        assert answer.headers["x-total-count"] == str(HEAVY)
        seen += [r["id"] for r in robots]
        path = answer.links.get("next", {}).get("url")
    assert len(sizes) >= 2, f"one page of {sizes[0]} bytes: the budget did not stop it"
    assert seen == [f"a-{i:04d}" for i in range(HEAVY)]


def test_a_walk_keeps_at_most_kept_robots_json(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(robot_list, "KEPT", 50)
    robots = [heavy_robot(i) for i in range(300)]
    rows = [((r.cloud, r.id), r) for r in robots]
    cache = RobotJson()
    after = None
    pages = 0
    while True:
        page = build_page(list(rows), [], after, 30, {}, {}, {}, cache)
        pages += 1
        assert len(cache) <= 50 + 30  # what is kept, and the page being built
        if page.next is None:
            break
        after = page.next
    assert pages == 10
    # A fleet within the bound is kept whole: the next walk encodes nothing anew.
    small = RobotJson()
    build_page(rows[:40], [], None, 40, {}, {}, {}, small)
    assert len(small) == 40
