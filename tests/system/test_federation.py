"""Three clouds with real processes: one pool of robots across providers."""

from __future__ import annotations

import concurrent.futures
import math
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from processes import (
    HEADERS,
    NO_SHEDDING,
    Cloud,
    follow,
    grabber_task,
    start_clouds,
    wait_until,
)

from robocloud.sim.roster import cloud_robots

NAMES = ("cloud-a", "cloud-b", "cloud-c")
# Robot seconds per wall second of the shared clouds and the chain: the
# slowest of every grabber sent to (1000, 1000) is done in about 6 s (1,245
# robot seconds: a-0011 drives 1,129 s, works 116 s), where 50 took 25 s.
SPEEDUP = 200.0


# For a cloud that is sent no request, so selects nothing: selections in a thread
# if any, rather than a forkserver and two worker processes to start with it.
NO_WORKERS = ["--selection-workers", "0"]


def shared_flags(name: str) -> list[str]:
    """The shared clouds' shorter periods, so that the tests see sooner what they wait for.

    Each cloud reconciles its loans every second (a quarter of a 4 s origin
    deadline; every 5 s by default): cloud-c, back, frees its robots sooner.
    cloud-a takes a robot silent for 2.5 s (5 by default) for offline: it
    notices sooner that cloud-c's robots fell silent. The tests send their
    requests to cloud-a only.
    """
    flags = ["--origin-deadline", "4"]
    return [*flags, "--offline-after", "2.5"] if name == "cloud-a" else [*flags, *NO_WORKERS]


def start_federation(
    tmp_path: Path,
    robots: int,
    speedup: float,
    chain: bool = False,
    shed: bool = True,
    flags: Callable[[str], list[str]] = lambda name: [],
) -> list[Cloud]:
    """Three clouds; ``shed=False`` turns their load shedding off (a burst test's clouds);
    ``flags(name)``: more flags for that cloud's IaaS."""
    shedding = [] if shed else NO_SHEDDING
    return start_clouds(
        tmp_path,
        NAMES,
        robots,
        speedup,
        chain=chain,
        iaas_args=lambda name: [*shedding, *flags(name)],
        together=True,
    )


class Shared:
    """The module's three clouds, and whether the last test that had them left them as new."""

    def __init__(self, clouds: list[Cloud]) -> None:
        self.clouds = clouds
        self.fresh = True  # as started: every robot at its place, no request


@pytest.fixture(scope="module")
def three_clouds(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Shared]:
    """The three clouds of the file's tests that need no special set-up (one start)."""
    clouds = start_federation(
        tmp_path_factory.mktemp("federation"), robots=20, speedup=SPEEDUP, flags=shared_flags
    )
    try:
        yield Shared(clouds)
    finally:
        for cloud in clouds:
            cloud.stop()


def as_new(clouds: list[Cloud], robots: bool = True) -> None:
    """Bring the shared clouds back to a fresh start: no request open, fresh robots, all three up.

    A test may stop a cloud or kill its IaaS: what is not running starts again
    (same ports, same store). Its requests still open are canceled; each
    simulator starts again, so that every robot is back at its place with its
    battery (the seeds are the same). ``robots=False``: only the simulators
    that stopped start again (a test that needs the three clouds listed with
    their robots, whatever their places and batteries).
    """
    for cloud in clouds:
        cloud.settle()
    for cloud in clouds:
        if cloud.sim is not None and cloud.sim.poll() is None:
            if not robots:
                continue
            cloud.sim.terminate()
            cloud.sim.wait(10)
        cloud.start_sim()
    if robots:
        for seed, cloud in enumerate(clouds):  # start_clouds gives the i-th cloud seed i
            at_their_places(cloud, seed)
    with clouds[0].client() as client:
        wait_until(
            lambda: [(c["cloud"], c["robots"]) for c in client.get("/v1/clouds").json()]
            == [(name, 20) for name in NAMES],
            30,
            "the three clouds back in the federation",
        )


def at_their_places(cloud: Cloud, seed: int) -> None:
    """Wait until the IaaS shows every robot where its simulator starts it: fresh states."""

    fresh = {r["id"]: r["position"] for r in cloud_robots(cloud.name, 20, seed=seed)}

    def back(robots: list[dict[str, Any]]) -> bool:
        shown = {r["id"]: r["position"] for r in robots}
        return shown.keys() == fresh.keys() and all(
            math.dist(shown[i], fresh[i]) < 0.1 for i in fresh
        )

    with cloud.client() as client:
        wait_until(
            lambda: back(client.get("/v1/robots").json()),
            30,
            f"{cloud.name}'s robots back at their places",
        )


@pytest.fixture
def federation(three_clouds: Shared) -> Iterator[list[Cloud]]:
    """The shared three clouds, as new: made so before the test when the last one changed them.

    Before rather than after: the module's last test leaves them to be stopped.
    """
    if not three_clouds.fresh:
        as_new(three_clouds.clouds)
    three_clouds.fresh = False
    yield three_clouds.clouds


@pytest.fixture
def federation_listed(three_clouds: Shared) -> Iterator[list[Cloud]]:
    """The shared three clouds running, each listed with its 20 robots, no request open;
    its robots wherever the last test left them."""
    if not three_clouds.fresh:
        as_new(three_clouds.clouds, robots=False)
    three_clouds.fresh = False
    yield three_clouds.clouds


def every_grabber_task(client: httpx.Client) -> tuple[dict[str, Any], set[str]]:
    """A task that needs every idle grabber of the federation: all three clouds serve it."""
    task, clouds = grabber_task(client)
    assert clouds == set(NAMES), "each cloud needs an idle grabber"
    return task, clouds


def coalition_clouds(request: dict[str, Any]) -> set[str]:
    return {a["cloud"] for a in request["coalition"] or []}


def test_a_request_is_served_by_all_three_clouds_then_one_is_canceled(
    federation: list[Cloud],
) -> None:
    with federation[0].client() as client:
        task, _ = every_grabber_task(client)
        rid = client.post("/v1/requests", json=task).json()["id"]
        dispatched = follow(
            client,
            rid,
            lambda r: r["state"] in ("dispatched", "underway", "failed", "rejected"),
            20,
            "dispatch",
        )
        assert coalition_clouds(dispatched) == set(NAMES), dispatched
        done = follow(
            client,
            rid,
            lambda r: r["state"] in ("completed", "failed"),
            90,
            "completion across three clouds",
        )
        assert done["state"] == "completed", done

        task, _ = every_grabber_task(client)
        # Far from (1000, 1000), where the first left its robots: each drives 1,273 m (636
        # robot seconds or more, 3 s at SPEEDUP) and is still on its way at the cancel.
        task["location"] = [1900.0, 100.0]
        rid = client.post("/v1/requests", json=task).json()["id"]
        underway = follow(
            client, rid, lambda r: r["state"] in ("underway", "failed"), 20, "underway"
        )
        assert coalition_clouds(underway) == set(NAMES)
        assert client.post(f"/v1/requests/{rid}/cancel").json()["state"] == "canceled"
    robots = {a["robot"] for a in underway["coalition"]}

    def all_free() -> bool:
        for cloud in federation:
            with cloud.client() as c:
                for r in c.get("/v1/robots").json():
                    if r["id"] in robots and (r["request"] is not None or r["status"] != "idle"):
                        return False
        return True

    wait_until(all_free, 15, "every canceled robot, in every cloud, to be idle and free")


def test_two_clouds_racing_never_book_a_robot_twice(tmp_path: Path) -> None:
    # 100 requests at once: load shedding would refuse some (503), which is not
    # what this test is about.
    clouds = start_federation(
        tmp_path,
        robots=20,
        speedup=2.0,
        shed=False,
        flags=lambda name: NO_WORKERS if name == "cloud-c" else [],  # sent to a and b only
    )
    try:
        task = {
            "location": [1000.0, 1000.0],
            "sensing": {"sound": 1},
            "actuating": {"grabber": 1},
            "max_robots": 2,
            "max_cost": 10_000.0,
            "max_time": 100_000.0,
            "min_battery": 0.0,
            "priority": "time",
        }

        def send(job: tuple[Cloud, int]) -> tuple[Cloud, str]:
            cloud, i = job
            with httpx.Client(base_url=cloud.url, headers=HEADERS, timeout=30) as c:
                return cloud, c.post("/v1/requests", json={**task, "label": str(i)}).json()["id"]

        jobs = [(clouds[i % 2], i) for i in range(100)]
        with concurrent.futures.ThreadPoolExecutor(32) as pool:
            sent = list(pool.map(send, jobs))

        def settled() -> list[dict[str, Any]] | None:
            out = []
            for cloud, rid in sent:
                with cloud.client() as c:
                    out.append(c.get(f"/v1/requests/{rid}").json())
            return out if all(r["state"] not in ("received", "selecting") for r in out) else None

        requests = wait_until(settled, 90, "all 100 requests to be selected", every=0.5)
        served = [r for r in requests if r["state"] in ("dispatched", "underway")]
        assert served, [(r["state"], r["reason"]) for r in requests]
        # The rest found no feasible coalition, or kept losing races for robots
        # (a bounded number of selections): either way with a reason.
        unserved = [r for r in requests if r not in served]
        assert all(r["state"] in ("rejected", "failed") and r["reason"] for r in unserved)
        print(
            f"served {len(served)}, rejected "
            f"{sum(r['state'] == 'rejected' for r in unserved)}, failed after repeated "
            f"conflicts {sum(r['state'] == 'failed' for r in unserved)}"
        )
        held = [a["robot"] for r in served for a in r["coalition"]]
        assert len(held) == len(set(held)), "a robot is in two active coalitions"
        assert len({c for r in served for c in coalition_clouds(r)}) >= 2
    finally:
        for cloud in clouds:
            cloud.stop()


def test_a_chain_serves_a_request_at_a_with_robots_of_c(tmp_path: Path) -> None:
    clouds = [
        Cloud(
            name,
            tmp_path,
            f"sqlite:///{tmp_path / f'{name}.db'}",
            robots=n,
            speedup=SPEEDUP,
            seed=3,
            iaas_args=[] if name == "cloud-a" else NO_WORKERS,  # the request goes to cloud-a
        )
        for name, n in zip(NAMES, (0, 0, 20), strict=True)
    ]
    clouds[1].peers = [clouds[0].zenoh]  # b connects to a
    clouds[2].peers = [clouds[1].zenoh]  # c connects to b; a and c never meet
    try:
        for cloud in clouds:
            cloud.launch_iaas()
        for cloud in clouds:
            cloud.wait_for_iaas()
        clouds[2].start_sim()
        clouds[2].wait_for_robots()
        with clouds[0].client() as client:
            wait_until(lambda: len(client.get("/v1/clouds").json()) == 3, 20, "three clouds")
            rid = client.post(
                "/v1/requests",
                json={
                    # Where c-0008 waits (the grabber that has the battery): its 127 s of
                    # work, under a second at SPEEDUP; it drove 1,154 s to (1000, 1000).
                    "location": [1102.8, 212.1],
                    "actuating": {"grabber": 1},
                    "max_robots": 2,
                    "max_cost": 10_000.0,
                    "max_time": 100_000.0,
                    "priority": "time",
                },
            ).json()["id"]
            done = follow(
                client,
                rid,
                lambda r: r["state"] in ("completed", "failed", "rejected"),
                60,
                "completion",
            )
            assert done["state"] == "completed", done
            assert coalition_clouds(done) == {"cloud-c"}
    finally:
        for cloud in clouds:
            cloud.stop()


def test_a_cloud_killed_mid_task_then_restarted(federation: list[Cloud]) -> None:
    a, _, c = federation
    with a.client() as client:
        task, _ = every_grabber_task(client)
        # Far: the robots are still driving at the kill (cloud-c's nearest grabber drives
        # 1,110 robot seconds, 5 s at SPEEDUP).
        task["location"] = [1900.0, 100.0]
        rid = client.post("/v1/requests", json=task).json()["id"]
        underway = follow(
            client, rid, lambda r: r["state"] in ("underway", "failed"), 20, "underway"
        )
        assert "cloud-c" in coalition_clouds(underway)
        c.kill_iaas()
        # cloud-c's robots fall silent for cloud-a: re-planned or failed, with a reason.
        over = follow(
            client,
            rid,
            lambda r: (
                r["state"] in ("completed", "failed")
                or any("replaced by" in (h["detail"] or "") for h in r["history"])
            ),
            30,
            "cloud-a to notice cloud-c is gone",
        )
        details = " ".join(h["detail"] or "" for h in over["history"]) + (over["reason"] or "")
        assert "c-" in details and "failed" in details, over
    c.start_iaas()
    c_robots = {a_["robot"] for a_ in underway["coalition"] if a_["cloud"] == "cloud-c"}
    with c.client() as cc:

        def released() -> bool:
            robots = {r["id"]: r for r in cc.get("/v1/robots").json()}
            return bool(robots) and all(
                robots[r]["request"] is None for r in c_robots if r in robots
            )

        wait_until(released, 30, "cloud-c to reconcile and free its robots")


def test_clouds_are_listed_and_a_stopped_one_disappears(federation_listed: list[Cloud]) -> None:
    with federation_listed[0].client() as client:
        clouds = client.get("/v1/clouds").json()
        assert [c["cloud"] for c in clouds] == list(NAMES)
        assert all(c["robots"] == 20 for c in clouds)
        federation_listed[2].stop()
        wait_until(
            lambda: [c["cloud"] for c in client.get("/v1/clouds").json()] == ["cloud-a", "cloud-b"],
            10,
            "cloud-c to leave the list",
        )
