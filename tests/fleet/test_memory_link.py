import pytest

from robocloud.domain import Capability, Robot
from robocloud.errors import NotFound
from robocloud.fleet import Assign, MemoryRobotLink, RobotLink, State


def robot(robot_id: str, x: float = 0.0, **changes: object) -> Robot:
    fields: dict[str, object] = {
        "id": robot_id,
        "cloud": "cloud-a",
        "position": [x, 0.0],
        "speed": 2.0,
        "battery": 80.0,
        "status": "idle",
        "travel_cost_per_m": 0.05,
        "capabilities": {"grabber": Capability(kind="actuating", time=60.0, cost=8.0)},
    }
    fields.update(changes)
    return Robot.model_validate(fields)


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


GO = Assign(request_id="r-1", location=[100.0, 0.0], capabilities=["grabber"])


def test_it_is_a_robot_link() -> None:
    link: RobotLink = MemoryRobotLink("cloud-a", [robot("a-1")])
    assert [r.id for r in link.robots()] == ["a-1"]


def test_an_assigned_robot_travels_works_and_ends_idle_there() -> None:
    link = MemoryRobotLink("cloud-a", [robot("a-1"), robot("a-2", x=5.0)])
    seen: list[State] = []
    link.on_state(seen.append)
    assert link.assign("a-1", GO).ok
    assert link.commands == [("a-1", GO)]
    link.step(25.0)  # half of the 50 s drive
    state = link.states()["a-1"]
    assert state.status == "busy" and state.task is not None
    assert (state.task.phase, state.position) == ("travel", [50.0, 0.0])
    assert state.task.progress == pytest.approx(25.0 / 110.0)
    link.step(50.0)
    assert link.states()["a-1"].task.phase == "work"  # type: ignore[union-attr]
    link.step(60.0)
    done = link.states()["a-1"]
    assert done.status == "idle" and done.position == [100.0, 0.0]
    assert done.task is not None and (done.task.phase, done.task.progress) == ("done", 1.0)
    assert done.battery == pytest.approx(80.0 - 1.0 - 1.2)
    link.step(1.0)
    assert link.states()["a-1"].task is None
    phases = [s.task.phase if s.task else None for s in seen if s.id == "a-1"]
    assert phases == ["travel", "travel", "work", "done", None]


def test_refusals_cancel_and_faults() -> None:
    clock = Clock()
    link = MemoryRobotLink("cloud-a", [robot("a-1"), robot("a-2")], offline_after=5.0, clock=clock)
    assert link.assign("a-1", GO).ok
    busy = link.assign("a-1", GO.model_copy(update={"request_id": "r-2"}))
    assert not busy.ok and busy.error == "robot a-1 is busy with request r-1."
    assert link.cancel("a-1", "r-1").ok
    assert link.states()["a-1"].status == "idle" and link.states()["a-1"].task is None
    assert link.cancel("a-1", "r-1").ok  # nothing to stop: still ok

    assert link.assign("a-2", GO).ok
    failed = link.fail("a-2")
    assert failed.status == "offline" and failed.task is not None
    assert failed.task.phase == "failed"

    link.silence("a-1")
    assert link.assign("a-1", GO).unanswered
    clock.now += 6.0
    assert {r.id: r.status for r in link.robots()} == {"a-1": "offline", "a-2": "offline"}
    link.recover("a-1")
    assert link.robots()[0].status == "idle"
    with pytest.raises(NotFound):
        link.silence("a-9")


def state_of(robot_id: str, seq: int = 1) -> State:
    fields = robot(robot_id).model_dump()
    return State.model_validate({**fields, "kind": "tribot", "seq": seq, "sent_at": float(seq)})


def test_silent_robots_are_forgotten_and_the_fleet_is_bounded(
    caplog: pytest.LogCaptureFixture,
) -> None:
    from robocloud.fleet.link import LatestStates

    clock = Clock()
    latest = LatestStates(
        "cloud-a", offline_after=5.0, clock=clock, forget_after=600.0, max_fleet=3
    )
    for i in range(3):
        assert latest.accept(state_of(f"a-{i}"))
    assert not latest.accept(state_of("a-3")), "a fourth robot is refused while three report"
    assert "the most it takes" in caplog.text
    clock.now += 300.0
    assert latest.accept(state_of("a-0", seq=2))  # a-0 keeps reporting
    assert [r.status for r in latest.robots()] == ["idle", "offline", "offline"]
    clock.now += 301.0  # a-1 and a-2 silent for 601 s, a-0 for 301 s
    assert latest.accept(state_of("a-3"))
    assert sorted(latest.states()) == ["a-0", "a-3"]
    assert sorted(latest.ages()) == ["a-0", "a-3"]


def test_a_robot_s_listed_age_is_that_of_what_it_last_said() -> None:
    """A gateway repeats a silent robot's last state (a new seq, the same sent_at)."""
    from robocloud.fleet.link import LatestStates

    clock = Clock()
    latest = LatestStates("cloud-a", offline_after=5.0, clock=clock)
    said = state_of("a-0", seq=1)
    assert latest.accept(said)
    for seq in (2, 3, 4):
        clock.now += 1.0
        assert latest.accept(said.model_copy(update={"seq": seq}))  # kept: a new seq
    assert latest.ages()["a-0"] == pytest.approx(3.0), "nothing new said for 3 s"
    clock.now += 1.0
    assert latest.accept(state_of("a-0", seq=5))  # sent_at 5.0: something new
    assert latest.ages()["a-0"] == pytest.approx(0.0)


def ordered(seq: int, sent_at: float, session: str | None = None, battery: float = 90.0) -> State:
    return state_of("a-0", seq).model_copy(
        update={"sent_at": sent_at, "session": session, "battery": battery}
    )


def test_a_new_session_starts_its_own_order_and_an_old_ones_replays_are_dropped() -> None:
    """Protocol 1.2's ``session``: seq orders one session's states; another session's
    state is newer only if sent later."""
    from robocloud.fleet.link import LatestStates

    clock = Clock()
    latest = LatestStates("cloud-a", offline_after=5.0, clock=clock, wall=clock)
    assert latest.accept(ordered(500, 100.0, "boot-1"))
    assert latest.accept(ordered(501, 100.5, "boot-1"))
    assert not latest.accept(ordered(500, 100.0, "boot-1")), "a replay of the same session"
    clock.now = 101.0
    # The robot restarts: a new session, counting from 0, sent later.
    assert latest.accept(ordered(0, 101.0, "boot-2"))
    # The old session's messages, replayed: another session, sent before.
    assert not latest.accept(ordered(502, 100.6, "boot-1"))
    assert not latest.accept(ordered(10**9, 100.9, "boot-1")), "a huge seq is no help"
    assert latest.accept(ordered(1, 101.2, "boot-2"))
    assert latest.states()["a-0"].session == "boot-2" and latest.states()["a-0"].seq == 1


def test_a_state_forged_ahead_is_overtaken_by_the_robots_next_ones(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Issue 25: a state with a huge seq and a sent_at ahead counts as sent when it
    arrived (plus ARRIVAL_SLACK): the robot's own states win again seconds later,
    whatever session the forger names (the real one's too: it is on the wire)."""
    from robocloud.fleet.link import LatestStates
    from robocloud.fleet.messages import ARRIVAL_SLACK

    for forged_session in (None, "boot-1", "made-up"):
        clock = Clock()
        latest = LatestStates("cloud-a", offline_after=5.0, clock=clock, wall=clock)
        assert latest.accept(ordered(7, 100.0, "boot-1"))
        clock.now = 100.5
        assert latest.accept(ordered(2**62, 100.5 + 290.0, forged_session, battery=1.0))
        clock.now = 101.0
        assert not latest.accept(ordered(8, 101.0, "boot-1")), "sent before the slack ends"
        clock.now = 100.5 + ARRIVAL_SLACK + 0.1
        assert latest.accept(ordered(9, clock.now, "boot-1", battery=80.0)), forged_session
        assert latest.states()["a-0"].battery == 80.0
        assert latest.overtaken() == {"overtaken": 1}
    # The log says how far ahead of its arrival the forged state claimed to be.
    assert caplog.text.count("claimed to be sent at 390.500, 290.0 s after it arrived") == 3
