"""The pure request life cycle (``robocloud.iaas.lifecycle``): every situation against every event.

The table says, for each situation a request can be in and each event it can
receive, the state it is in afterwards and the effects it asks for, in order.
The hypothesis test below plays random sequences of events over several
requests that compete for the same robots, with a model of the store, and
checks the invariants the life cycle promises.
"""

from __future__ import annotations

from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robocloud.domain import FINAL_STATES, Task
from robocloud.iaas import lifecycle as lc

TASK = Task.model_validate(
    {
        "location": [0.0, 0.0],
        "sensing": {"light": 1},
        "actuating": {"grabber": 1},
        "max_robots": 3,
        "max_cost": 100.0,
        "max_time": 300.0,
    }
)
GRABBER = TASK.model_copy(update={"sensing": {}, "max_robots": 2})
NOW = lc.Now(mono=100.0, wall=1000.0)
LATER = lc.Now(mono=100.5, wall=1000.5)
MUCH_LATER = lc.Now(mono=110.0, wall=1010.0)

BOTH = lc.Member("a-1", "cloud-a", ("grabber", "light"), 30.0, 5.0, since=100.0, heard_at=100.0)
LIGHT = replace(BOTH, capabilities=("light",), phase="travel", confirmed=True)
NEW = lc.Member("a-9", "cloud-b", ("grabber", "light"), 40.0, 6.0)

RID = "req-aaaaaaaaaaaa"
FRESH = lc.Life(RID, TASK)
SITUATIONS: dict[str, lc.Life] = {
    "received": FRESH,
    "selecting": replace(FRESH, state="selecting", attempt=lc.Attempt("dispatch", 1, TASK)),
    "reserving": replace(
        FRESH,
        state="selecting",
        attempt=lc.Attempt("dispatch", 1, TASK, "reserving", chosen=(BOTH,)),
    ),
    "assigning": replace(
        FRESH,
        state="selecting",
        attempt=lc.Attempt("dispatch", 1, TASK, "assigning", chosen=(BOTH,)),
    ),
    "dispatched": replace(FRESH, state="dispatched", members={"a-1": BOTH}, dispatched_at=1000.0),
    "underway": replace(
        FRESH,
        state="underway",
        members={"a-1": replace(BOTH, phase="travel", progress=0.2, confirmed=True)},
        dispatched_at=1000.0,
    ),
    "replacing": replace(
        FRESH,
        state="underway",
        members={"a-1": LIGHT},
        dispatched_at=1000.0,
        attempt=lc.Attempt("replace", 1, GRABBER, replacing=("a-3",)),
    ),
    "completed": replace(FRESH, state="completed"),
    "rejected": replace(FRESH, state="rejected"),
    "canceled": replace(FRESH, state="canceled"),
    "failed": replace(FRESH, state="failed"),
    "canceled while reserving": replace(
        FRESH,
        state="canceled",
        attempt=lc.Attempt("dispatch", 1, TASK, "reserving", chosen=(BOTH,)),
    ),
    "canceled while assigning": replace(
        FRESH,
        state="canceled",
        attempt=lc.Attempt("dispatch", 1, TASK, "assigning", chosen=(BOTH,)),
    ),
}

EVENTS: dict[str, tuple[lc.Event, lc.Now]] = {
    "start": (lc.Start(), NOW),
    "resume": (lc.Start(resumed=True), NOW),
    "selected": (lc.Selected((NEW,), {"chosen": None}), NOW),
    "none": (lc.Selected(None, {}, "no robot brings grabber"), NOW),
    "reserved": (lc.Reserved(()), NOW),
    "taken": (lc.Reserved(("a-1",)), NOW),
    "acked": (lc.Acked({}), NOW),
    "refused": (lc.Acked({"a-1": "robot a-1 did not answer."}), NOW),
    "travel": (lc.RobotReport("a-1", "busy", 80.0, "travel", 0.4), LATER),
    "done": (lc.RobotReport("a-1", "idle", 70.0, "done", 1.0), LATER),
    "died": (lc.RobotReport("a-1", "offline", 0.0, "failed", 0.5), LATER),
    "last done": (lc.RobotReport("a-1", "idle", 70.0, None, 0.0, last_phase="done"), LATER),
    "other": (lc.RobotReport("a-1", "idle", 70.0), LATER),
    "tick": (lc.Tick(), LATER),
    "silence": (lc.Tick(), MUCH_LATER),
    "cancel": (lc.CancelAsked(), NOW),
    "loan ended": (lc.LoanEnded("a-1", "cloud-b", "cloud-a was unreachable"), NOW),
    "crash": (lc.Crashed("boom"), NOW),
}

# Shorthands for the effects' names in the table.
END = ["Commit", "StopRobots", "Release", "Unfollow"]  # a final state with robots at work
FAIL_ONE = ["Unfollow", "StopRobots", "Release", "Note"]  # a robot failed
REPLACE = [*FAIL_ONE, "Select"]  # ... and a replacement is selected
NOTHING: tuple[str | None, list[str]] = (None, [])  # state unchanged, no effect

# situation -> event -> (state afterwards, or None for unchanged; effect names in order).
# An event missing from a situation's row is NOTHING.
TABLE: dict[str, dict[str, tuple[str | None, list[str]]]] = {
    "received": {
        "start": ("selecting", ["Commit", "Select"]),
        "resume": ("selecting", ["ReleaseAll", "Note", "Commit", "Select"]),
        "cancel": ("canceled", ["Commit"]),
        "loan ended": (None, ["Note"]),
        "crash": ("failed", ["Commit"]),
    },
    "selecting": {
        "selected": (None, ["Reserve"]),
        "none": ("rejected", ["Commit"]),
        "cancel": ("canceled", ["Commit"]),
        "loan ended": (None, ["Note"]),
        "crash": ("failed", ["Commit"]),
    },
    "reserving": {
        "reserved": (None, ["Follow", "Assign"]),
        "taken": (None, ["Note", "Select"]),
        "cancel": ("canceled", ["Commit"]),
        "loan ended": (None, ["Note"]),
        "crash": ("failed", ["Commit"]),
    },
    "assigning": {
        "acked": ("dispatched", ["Commit", "Confirm"]),
        "refused": (None, ["StopRobots", "Unfollow", "Release", "Note", "Select"]),
        "cancel": ("canceled", END),
        "loan ended": (None, ["Note"]),
        "crash": ("failed", END),
    },
    "dispatched": {
        "start": (None, ["Follow", "Note"]),
        "resume": (None, ["Follow", "Note"]),
        "travel": ("underway", ["Commit"]),
        "done": ("completed", ["Commit", "Commit", "Release", "Unfollow"]),
        "died": (None, REPLACE),
        "last done": ("completed", ["Commit", "Commit", "Release", "Unfollow"]),
        "silence": (None, REPLACE),
        "cancel": ("canceled", END),
        "loan ended": (None, ["Note", *REPLACE]),
        "crash": ("failed", END),
    },
    "underway": {
        "start": (None, ["Follow", "Note"]),
        "resume": (None, ["Follow", "Note"]),
        "travel": (None, ["Publish"]),
        "done": ("completed", ["Commit", "Release", "Unfollow"]),
        "died": (None, REPLACE),
        "last done": ("completed", ["Commit", "Release", "Unfollow"]),
        "other": (None, REPLACE),
        "silence": (None, REPLACE),
        "cancel": ("canceled", END),
        "loan ended": (None, ["Note", *REPLACE]),
        "crash": ("failed", END),
    },
    "replacing": {
        "selected": (None, ["Reserve"]),
        "none": ("failed", END),
        "travel": (None, ["Publish"]),
        "done": (None, ["Publish"]),
        "died": (None, FAIL_ONE),
        "last done": (None, ["Publish"]),
        "other": (None, FAIL_ONE),
        "silence": (None, FAIL_ONE),
        "cancel": ("canceled", END),
        "loan ended": (None, ["Note", *FAIL_ONE]),
        "crash": ("failed", END),
    },
    "completed": {},
    "rejected": {},
    "canceled": {},
    "failed": {},
    "canceled while reserving": {"reserved": (None, ["Release"])},
    "canceled while assigning": {
        "acked": (None, ["StopRobots", "Release"]),
        "refused": (None, ["StopRobots", "Release"]),
    },
}


@pytest.mark.parametrize("situation", list(SITUATIONS))
@pytest.mark.parametrize("event_name", list(EVENTS))
def test_every_situation_against_every_event(situation: str, event_name: str) -> None:
    life = SITUATIONS[situation]
    event, now = EVENTS[event_name]
    expected_state, expected_effects = TABLE[situation].get(event_name, NOTHING)
    after, effects = lc.decide(life, event, now)
    assert after.state == (expected_state or life.state)
    assert [type(e).__name__ for e in effects] == expected_effects
    if life.final:
        assert after.state == life.state, "a final state never changes"


def test_the_table_covers_every_event_type() -> None:
    sent = {type(event) for event, _ in EVENTS.values()}
    assert sent == set(lc._HANDLERS)


def test_a_late_acknowledgement_gets_a_stop_and_the_robot_is_not_chosen_again() -> None:
    life = SITUATIONS["assigning"]
    _, effects = lc.decide(life, EVENTS["refused"][0], NOW)
    stop = next(e for e in effects if isinstance(e, lc.StopRobots))
    assert stop.robots == (("a-1", "cloud-a"),)
    select = next(e for e in effects if isinstance(e, lc.Select))
    assert "a-1" in select.exclude
    note = next(e for e in effects if isinstance(e, lc.Note))
    assert "did not answer" in note.detail and "attempt 2" in note.detail
    assert ".;" not in note.detail  # the robot's sentence loses its full stop before the "; "


def test_a_refusal_names_the_robots_of_the_try_told_to_stop() -> None:
    other = lc.Member("c-7", "cloud-c", ("light",), 30.0, 5.0)
    life = replace(
        FRESH, state="selecting",
        attempt=lc.Attempt("dispatch", 1, TASK, "assigning", chosen=(BOTH, other)),
    )
    _, effects = lc.decide(life, lc.Acked({"a-1": "robot a-1 is charging, not idle."}), NOW)
    stop = next(e for e in effects if isinstance(e, lc.StopRobots))
    assert stop.robots == (("a-1", "cloud-a"), ("c-7", "cloud-c"))
    note = next(e for e in effects if isinstance(e, lc.Note))
    assert note.detail == (
        "robot a-1 refused the task: robot a-1 is charging, not idle; c-7 told to stop; "
        "selecting again (attempt 2)"
    )


@pytest.mark.parametrize(
    ("report", "why"),
    [
        (lc.RobotReport("a-1", "offline", 0.0, "failed", 0.5), "its battery died"),
        (lc.RobotReport("a-1", "offline", 40.0, "failed", 0.5), "it went offline"),
        # A fleet gateway's vehicle dropped the order while online (VDA 5050).
        (lc.RobotReport("a-1", "busy", 40.0, "failed", 0.5),
         "it reported that it cannot finish its task"),
        (lc.RobotReport("a-1", "idle", 40.0, None, 0.0, last_phase="failed"),
         "it reported that it cannot finish its task"),
        # Protocol 1.1: the robot's own sentence, printable characters only.
        (lc.RobotReport("a-1", "idle", 40.0, "failed", 0.5,
                        reason="navigation preempted\nby another goal (ab12)."),
         "it says: navigation preempted by another goal (ab12)"),
    ],
)
def test_a_failure_says_why_the_robot_failed(report: lc.RobotReport, why: str) -> None:
    _, effects = lc.decide(SITUATIONS["underway"], report, LATER)
    notes = [e.detail for e in effects if isinstance(e, lc.Note)]
    commits = [e.detail for e in effects if isinstance(e, lc.Commit)]
    assert any(f"robot a-1 failed: {why}" in (d or "") for d in notes + commits), effects


def test_dispatch_stores_the_assignments_and_when() -> None:
    after, effects = lc.decide(SITUATIONS["assigning"], lc.Acked({}), NOW)
    commit = effects[0]
    assert isinstance(commit, lc.Commit) and commit.selection is not None
    assert commit.selection["dispatched_at"] == NOW.wall
    assert [a["robot"] for a in commit.selection["assignments"]] == ["a-1"]
    assert commit.detail == "1 robot: a-1"
    assert after.dispatched_at == NOW.wall and set(after.members) == {"a-1"}


def test_a_replacement_asks_for_what_is_missing_within_what_is_left() -> None:
    life = SITUATIONS["dispatched"]
    # 100 wall seconds after dispatch, robots 10 times faster: 1,000 s of robot time
    # would be spent, more than max_time; at 1x, 100 s is spent.
    later = lc.Now(mono=100.0, wall=1100.0)
    _, effects = lc.decide(life, lc.LoanEnded("a-1", "cloud-b", "gone"), later)
    select = effects[-1]
    assert isinstance(select, lc.Select)
    assert select.task.required == {"grabber": 1, "light": 1}
    assert select.task.max_time == pytest.approx(200.0)
    assert select.task.max_cost == pytest.approx(100.0)
    assert select.offset == pytest.approx(100.0)
    fast = replace(life, rules=lc.Rules(time_scale=10.0))
    after, effects = lc.decide(fast, lc.LoanEnded("a-1", "cloud-b", "gone"), later)
    assert after.state == "failed"
    assert "no time is left of max_time 300 s" in str(effects[5])


def test_a_replacement_updates_the_coalition_now() -> None:
    replacing = replace(
        SITUATIONS["replacing"],
        attempt=lc.Attempt(
            "replace",
            1,
            GRABBER,
            "assigning",
            chosen=(replace(NEW, offset=50.0),),
            replacing=("a-3",),
        ),
    )
    _, effects = lc.decide(replacing, lc.Acked({}), NOW)
    save = effects[0]
    assert isinstance(save, lc.SaveSelection)
    assert save.selection["current"] == {
        "robots": ["a-1", "a-9"],
        "time": pytest.approx(90.0),  # a-9 sent 50 s after dispatch, t_i 40 s
        "cost": pytest.approx(11.0),
        "size": 2,
    }
    assert save.selection["replacements"] == [{"failed": ["a-3"], "by": ["a-9"]}]
    note = effects[2]
    assert isinstance(note, lc.Note) and note.detail == "robot a-3 replaced by a-9"


def test_after_a_restart_a_robot_that_does_not_report_the_request_fails() -> None:
    life, _ = lc.decide(SITUATIONS["underway"], lc.Start(resumed=True), NOW)
    other = lc.RobotReport("a-1", "idle", 70.0)
    # Within the restart's grace (10 s): the robot may still be reconnecting.
    quiet, effects = lc.decide(life, other, lc.Now(NOW.mono + 6.0, NOW.wall + 6.0))
    assert effects == []
    _, effects = lc.decide(quiet, lc.Tick(), lc.Now(NOW.mono + 9.0, NOW.wall + 9.0))
    assert effects == [], "not silent within the grace"
    late = lc.Now(NOW.mono + 11.0, NOW.wall + 11.0)
    _, effects = lc.decide(quiet, other, late)
    note = next(e for e in effects if isinstance(e, lc.Note))
    assert note.detail == "robot a-1 failed: it no longer reports this request after the restart"


def test_a_selection_cut_short_with_nothing_found_fails_rather_than_rejects() -> None:
    cut = lc.Selected(None, {}, "the time budget of 2 s ran out", complete=False)
    after, effects = lc.decide(SITUATIONS["selecting"], cut, NOW)
    assert after.state == "failed"
    assert effects == [lc.Commit("failed", "the time budget of 2 s ran out", None, {})]


def test_too_many_attempts_fail_the_request_with_the_reason() -> None:
    life = replace(
        SITUATIONS["reserving"],
        attempt=lc.Attempt("dispatch", 8, TASK, "reserving", chosen=(BOTH,)),
    )
    after, effects = lc.decide(life, lc.Reserved(("a-1",)), NOW)
    assert after.state == "failed"
    commit = effects[0]
    assert isinstance(commit, lc.Commit)
    assert commit.reason is not None and "in 8 attempts" in commit.reason


# -- random sequences over competing requests -------------------------------------------

ROBOTS = [f"r-{i}" for i in range(5)]
CAPS = {"r-0": ("grabber", "light"), "r-1": ("grabber",), "r-2": ("light",)}
CAPS |= {"r-3": ("grabber", "light"), "r-4": ("light",)}


class World:
    """Several requests' lives, a model of the store (one holder per robot) and the robots."""

    def __init__(self, requests: int) -> None:
        self.lives = {
            f"req-{i}": lc.Life(f"req-{i}", TASK, rules=lc.Rules(attempts=3))
            for i in range(requests)
        }
        self.holder: dict[str, str] = {}  # robot -> request, as the store keeps it
        self.pending: dict[str, lc.Effect] = {}  # request -> its operation in flight
        self.told: dict[str, set[str]] = {rid: set() for rid in self.lives}  # stop commands
        self.released: dict[str, set[str]] = {rid: set() for rid in self.lives}
        self.now = lc.Now(0.0, 0.0)

    def step(self, rid: str, event: lc.Event) -> None:
        before = self.lives[rid]
        after, effects = lc.decide(before, event, self.now)
        if before.final:
            assert after.state == before.state, "a final state never changes"
            assert not any(isinstance(e, lc.Commit) for e in effects)
        self.lives[rid] = after
        for effect in effects:
            self.carry_out(rid, effect)
        self.check()

    def carry_out(self, rid: str, effect: lc.Effect) -> None:
        match effect:
            case lc.Commit(state) if state in FINAL_STATES:
                # The store releases every reservation of a request that ends.
                self.holder = {r: h for r, h in self.holder.items() if h != rid}
            case lc.Select() | lc.Reserve() | lc.Assign():
                self.pending[rid] = effect
            case lc.StopRobots(robots):
                self.told[rid] |= {r for r, _ in robots}
            case lc.Release(robots):
                self.released[rid] |= {r for r, _ in robots}
                for robot, _ in robots:
                    if self.holder.get(robot) == rid:
                        del self.holder[robot]
            case lc.ReleaseAll():
                self.holder = {r: h for r, h in self.holder.items() if h != rid}

    def answer(self, rid: str, data: st.DataObject) -> lc.Event | None:
        """The result of the request's operation in flight, as the world would give it."""
        effect = self.pending.pop(rid, None)
        match effect:
            case lc.Select(_, exclude):
                free = [r for r in ROBOTS if r not in exclude]
                pick = (
                    data.draw(st.lists(st.sampled_from(free), unique=True, max_size=2))
                    if free
                    else []
                )
                if not pick:
                    return lc.Selected(None, {}, "nothing fits")
                chosen = tuple(lc.Member(r, "cloud-a", CAPS[r], 10.0, 1.0) for r in pick)
                return lc.Selected(chosen, {"chosen": None})
            case lc.Reserve(robots):
                if self.lives[rid].final:
                    return lc.Reserved(tuple(r for r, _ in robots))  # the store refuses
                taken = tuple(r for r, _ in robots if self.holder.get(r, rid) != rid)
                if not taken:
                    for robot, _ in robots:
                        self.holder[robot] = rid
                return lc.Reserved(taken)
            case lc.Assign(members):
                refused = data.draw(
                    st.lists(st.sampled_from([m.robot for m in members]), unique=True)
                )
                return lc.Acked({r: "busy" for r in refused})
        return None

    def check(self) -> None:
        working: dict[str, str] = {}
        for rid, life in self.lives.items():
            if life.final:
                continue
            for member in life.members.values():
                assert member.robot not in working, (
                    f"robot {member.robot} is in {working[member.robot]} and {rid}"
                )
                working[member.robot] = rid
                assert self.holder.get(member.robot) == rid, "a member is reserved for its request"

    def check_finished(self, rid: str, commanded: set[str]) -> None:
        """A finished request holds nothing; every robot it sent is told to stop or finished."""
        life = self.lives[rid]
        assert life.final
        assert not any(h == rid for h in self.holder.values()), "its reservations are gone"
        finished = {r for r, m in life.members.items() if m.phase == "done"}
        assert commanded - finished <= self.told[rid], (
            f"robots {commanded - finished - self.told[rid]} of a {life.state} request "
            "were not told to stop"
        )
        assert set(life.members) <= self.released[rid] | finished


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_random_sequences_keep_the_invariants(data: st.DataObject) -> None:
    world = World(requests=3)
    commanded: dict[str, set[str]] = {rid: set() for rid in world.lives}
    for rid in world.lives:
        world.step(rid, lc.Start())
    for _ in range(data.draw(st.integers(10, 80))):
        rid = data.draw(st.sampled_from(sorted(world.lives)))
        life = world.lives[rid]
        kind = data.draw(
            st.sampled_from(["answer"] * 4 + ["report"] * 4 + ["tick"] * 2 + ["cancel", "crash"])
        )
        event: lc.Event | None = None
        if kind == "answer":
            pending = world.pending.get(rid)
            if isinstance(pending, lc.Assign):
                commanded[rid] |= {m.robot for m in pending.members}
            event = world.answer(rid, data)
        elif kind == "report":
            robot = data.draw(st.sampled_from(sorted(life.members) * 3 + ROBOTS))
            phase = data.draw(st.sampled_from([None, "travel", "work", *["done"] * 3, "failed"]))
            last = data.draw(st.sampled_from([None, "done"]))
            status = "offline" if phase == "failed" else "busy"
            event = lc.RobotReport(robot, status, 50.0, phase, 0.5, last)
        elif kind == "tick":
            world.now = lc.Now(world.now.mono + data.draw(st.floats(0.1, 8.0)), world.now.wall + 1)
            event = lc.Tick()
        elif kind == "cancel":
            event = lc.CancelAsked()
        else:
            event = lc.Crashed("boom")
        if event is not None:
            world.step(rid, event)
        assert life.final <= world.lives[rid].final  # once final, always final
    # Let every operation in flight come back, as the actor does before it ends.
    for rid in sorted(world.lives):
        while rid in world.pending:
            pending = world.pending[rid]
            if isinstance(pending, lc.Assign):
                commanded[rid] |= {m.robot for m in pending.members}
            event = world.answer(rid, data)
            if event is not None:
                world.step(rid, event)
        if not world.lives[rid].final:
            world.step(rid, lc.CancelAsked())
        world.check_finished(rid, commanded[rid])
