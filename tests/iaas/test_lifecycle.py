"""The pure request life cycle (``robocloud.iaas.lifecycle``): every situation against every event.

The table says, for each situation a request can be in and each event it can
receive, the state it is in afterwards and the effects it asks for, in order.
The hypothesis test below plays random sequences of events over several
requests that compete for the same robots, with a model of the store, and
checks the invariants the life cycle promises.

Why one long file: the table and the properties test one pure function
(``decide``) and share its situations and events.
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

BOTH = lc.Member(
    "a-1", "cloud-a", ("grabber", "light"), 30.0, 5.0,
    since=100.0, heard_at=100.0, progressed_at=100.0,
)  # fmt: skip
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
    "refused": (lc.Acked({"a-1": "robot a-1 does not have grabber."}), NOW),
    "no ack": (
        lc.Acked(
            {"a-1": "robot a-1 did not answer within the ack deadline (2 s)."},
            frozenset({"a-1"}),
        ),
        NOW,
    ),
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
FAIL_ONE = ["Unfollow", "StopRobots", "Release", "Note", "RobotFailed"]  # a robot failed
REPLACE = [*FAIL_ONE, "Select"]  # ... and a replacement is selected
NOTHING: tuple[str | None, list[str]] = (None, [])  # state unchanged, no effect
UNCLAIM: tuple[str | None, list[str]] = (None, ["Unclaim"])  # a late choice is free again

# situation -> event -> (state afterwards, or None for unchanged; effect names in order).
# An event missing from a situation's row is NOTHING.
TABLE: dict[str, dict[str, tuple[str | None, list[str]]]] = {
    "received": {
        "selected": UNCLAIM,
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
        "selected": UNCLAIM,
        "reserved": (None, ["Follow", "Unclaim", "Assign"]),
        "taken": (None, ["Unclaim", "Note", "Select"]),
        "cancel": ("canceled", ["Commit"]),
        "loan ended": (None, ["Note"]),
        "crash": ("failed", ["Commit"]),
    },
    "assigning": {
        "acked": ("dispatched", ["Commit", "Confirm"]),
        "selected": UNCLAIM,
        "refused": (None, ["StopRobots", "Unfollow", "Release", "Note", "Select"]),
        "no ack": (
            None, ["StopRobots", "Unfollow", "Release", "RobotFailed", "Note", "Select"]
        ),
        "cancel": ("canceled", END),
        "loan ended": (None, ["Note"]),
        "crash": ("failed", END),
    },
    "dispatched": {
        "start": (None, ["Follow", "Note"]),
        "resume": (None, ["Follow", "Note"]),
        "selected": UNCLAIM,
        "travel": ("underway", ["Commit"]),
        "done": ("completed", ["RobotDone", "Commit", "Commit", "Release", "Unfollow"]),
        "died": (None, REPLACE),
        "last done": ("completed", ["RobotDone", "Commit", "Commit", "Release", "Unfollow"]),
        "silence": (None, REPLACE),
        "cancel": ("canceled", END),
        "loan ended": (None, ["Note", *REPLACE]),
        "crash": ("failed", END),
    },
    "underway": {
        "start": (None, ["Follow", "Note"]),
        "resume": (None, ["Follow", "Note"]),
        "selected": UNCLAIM,
        "travel": (None, ["Publish"]),
        "done": ("completed", ["RobotDone", "Commit", "Release", "Unfollow"]),
        "died": (None, REPLACE),
        "last done": ("completed", ["RobotDone", "Commit", "Release", "Unfollow"]),
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
        "done": (None, ["RobotDone", "Publish"]),
        "died": (None, FAIL_ONE),
        "last done": (None, ["RobotDone", "Publish"]),
        "other": (None, FAIL_ONE),
        "silence": (None, FAIL_ONE),
        "cancel": ("canceled", END),
        "loan ended": (None, ["Note", *FAIL_ONE]),
        "crash": ("failed", END),
    },
    "completed": {"selected": UNCLAIM},
    "rejected": {"selected": UNCLAIM},
    "canceled": {"selected": UNCLAIM},
    "failed": {"selected": UNCLAIM},
    "canceled while reserving": {
        "selected": UNCLAIM,
        "reserved": (None, ["Unclaim", "Release"]),
        "taken": UNCLAIM,
    },
    "canceled while assigning": {
        "selected": UNCLAIM,
        "acked": (None, ["StopRobots", "Release"]),
        "refused": (None, ["StopRobots", "Release"]),
        "no ack": (None, ["StopRobots", "Release"]),
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
    _, effects = lc.decide(life, EVENTS["no ack"][0], NOW)
    stop = next(e for e in effects if isinstance(e, lc.StopRobots))
    assert stop.robots == (("a-1", "cloud-a"),)
    select = next(e for e in effects if isinstance(e, lc.Select))
    assert "a-1" in select.exclude
    note = next(e for e in effects if isinstance(e, lc.Note))
    assert "did not answer within the ack deadline" in note.detail and "attempt 2" in note.detail
    assert "refused" not in note.detail, "no answer is not a refusal"
    assert ".;" not in note.detail  # the robot's sentence loses its full stop before the "; "
    failed = next(e for e in effects if isinstance(e, lc.RobotFailed))
    assert (failed.robot, failed.cause) == ("a-1", "no_ack")


def test_a_refusal_is_said_as_one_and_does_not_count_against_the_robot() -> None:
    _, effects = lc.decide(SITUATIONS["assigning"], EVENTS["refused"][0], NOW)
    note = next(e for e in effects if isinstance(e, lc.Note))
    assert note.detail.startswith("robot a-1 refused the task: robot a-1 does not have grabber;")
    assert not any(isinstance(e, lc.RobotFailed) for e in effects)


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
         "it reported that it cannot finish its task: navigation preempted by another goal "
         "(ab12)"),
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
    commit = next(e for e in effects if isinstance(e, lc.Commit))
    assert "no time is left of max_time 300 s" in str(commit.reason)


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
    assert effects[0] == lc.Unclaim((("a-1", "cloud-a"),))
    commit = effects[1]
    assert isinstance(commit, lc.Commit)
    assert commit.reason is not None and "in 8 attempts" in commit.reason


# -- the watchdog --------------------------------------------------------------------------


def _effect(effects: list[lc.Effect], kind: type[lc.Effect]) -> lc.Effect:
    return next(e for e in effects if isinstance(e, kind))


def test_a_robot_past_its_expected_finish_is_stopped_and_replaced() -> None:
    life = SITUATIONS["underway"]  # a-1: t_i 30 s, dispatched at wall 1000
    # Its tolerance is the larger of 50% of 30 s and 30 s: due at 1060.
    heard = lc.Now(mono=159.0, wall=1059.0)
    on_time = replace(life, members={"a-1": replace(life.members["a-1"], heard_at=159.0,
                                                    progressed_at=159.0)})
    assert lc.decide(on_time, lc.Tick(), heard)[1] == []
    after, effects = lc.decide(on_time, lc.Tick(), lc.Now(mono=160.0, wall=1061.0))
    failed = _effect(effects, lc.RobotFailed)
    assert isinstance(failed, lc.RobotFailed) and failed.cause == "overrun"
    assert _effect(effects, lc.StopRobots) == lc.StopRobots((("a-1", "cloud-a"),))
    note = _effect(effects, lc.Note)
    assert isinstance(note, lc.Note)
    assert note.detail == (
        "robot a-1 failed: it is past its expected finish (30 s robot time, plus 30 s of "
        "tolerance) by 1 s"
    )
    assert isinstance(effects[-1], lc.Select), "a replacement is selected"
    assert "a-1" in after.excluded


def test_the_tolerance_is_half_the_expected_time_when_that_is_more_than_30_s() -> None:
    rules = lc.Rules()
    assert rules.tolerance(30.0) == 30.0
    assert rules.tolerance(200.0) == 100.0
    # Under a speed-up the expected time shrinks, the floor of the tolerance not:
    # 200 robot s are 20 wall s at x10, and 50% of them 10 s, under the 30 s floor.
    assert lc.Rules(time_scale=10.0).due(1000.0, 200.0) == pytest.approx(1050.0)
    assert lc.Rules(time_scale=10.0).due(1000.0, 1000.0) == pytest.approx(1150.0)


def test_progress_reported_extends_nothing() -> None:
    life = SITUATIONS["underway"]
    late = lc.Now(mono=160.0, wall=1061.0)
    progressing = lc.RobotReport("a-1", "busy", 80.0, "travel", 0.9)
    life, _ = lc.decide(life, progressing, late)
    _, effects = lc.decide(life, lc.Tick(), late)
    failed = _effect(effects, lc.RobotFailed)
    assert isinstance(failed, lc.RobotFailed) and failed.cause == "overrun"


def test_a_robot_that_reports_no_progress_has_stalled() -> None:
    life = SITUATIONS["underway"]  # progress 0.2 since mono 100
    same = lc.RobotReport("a-1", "busy", 80.0, "travel", 0.2)
    for mono in (110.0, 120.0, 129.0):
        life, effects = lc.decide(life, same, lc.Now(mono, 1000.0 + mono - 100.0))
        assert not any(isinstance(e, lc.RobotFailed) for e in effects)
        life, effects = lc.decide(life, lc.Tick(), lc.Now(mono, 1000.0 + mono - 100.0))
        assert effects == []
    _, effects = lc.decide(life, lc.Tick(), lc.Now(131.0, 1031.0))
    failed = _effect(effects, lc.RobotFailed)
    assert isinstance(failed, lc.RobotFailed) and failed.cause == "stalled"
    assert "no progress for 31 s" in failed.why


def test_a_stale_report_moves_nothing_back() -> None:
    life = SITUATIONS["underway"]
    working = lc.RobotReport("a-1", "busy", 80.0, "work", 0.6)
    life, _ = lc.decide(life, working, lc.Now(105.0, 1005.0))
    for stale in (
        lc.RobotReport("a-1", "busy", 80.0, "travel", 0.3),  # an older phase, replayed
        lc.RobotReport("a-1", "busy", 80.0, "work", 0.5),  # progress going back
    ):
        after, _ = lc.decide(life, stale, lc.Now(110.0, 1010.0))
        member = after.members["a-1"]
        assert (member.phase, member.progress) == ("work", 0.6)
        assert member.progressed_at == 105.0, "a stale report is no progress"
        assert member.heard_at == 110.0, "but the robot is heard"


def test_a_robot_s_reason_for_failing_reaches_the_history() -> None:
    report = lc.RobotReport(
        "a-1", "idle", 80.0, "failed", 0.4, reason="navigation aborted: no path to the goal."
    )
    _, effects = lc.decide(SITUATIONS["underway"], report, LATER)
    note = _effect(effects, lc.Note)
    assert isinstance(note, lc.Note)
    assert note.detail == (
        "robot a-1 failed: it reported that it cannot finish its task: navigation aborted: "
        "no path to the goal"
    )
    failed = _effect(effects, lc.RobotFailed)
    assert isinstance(failed, lc.RobotFailed) and failed.cause == "reported"


def test_a_request_is_never_underway_past_max_time_plus_its_tolerance() -> None:
    done = replace(LIGHT, phase="done", progress=1.0)
    life = replace(SITUATIONS["replacing"], members={"a-1": done})  # waits for a grabber
    due = 1000.0 + 300.0 + 150.0
    _, effects = lc.decide(life, lc.Tick(), lc.Now(mono=101.0, wall=due - 1))
    assert effects == []
    after, effects = lc.decide(life, lc.Tick(), lc.Now(mono=101.0, wall=due + 1))
    assert after.state == "failed"
    commit = _effect(effects, lc.Commit)
    assert isinstance(commit, lc.Commit)
    assert commit.reason == (
        "it ran past its max_time of 300 s (robot time) plus the tolerance of 150 s; "
        "no robot was left working"
    )


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
        # Robots a selection chose, claimed by the shell until an Unclaim.
        self.claimed: dict[str, set[str]] = {rid: set() for rid in self.lives}
        self.commanded: dict[str, set[str]] = {rid: set() for rid in self.lives}  # ever sent
        self.done: dict[str, set[str]] = {rid: set() for rid in self.lives}  # parts finished
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
            case lc.Assign(members):
                self.pending[rid] = effect
                self.commanded[rid] |= {m.robot for m in members}
            case lc.Select() | lc.Reserve():
                self.pending[rid] = effect
            case lc.Unclaim(robots):
                self.claimed[rid] -= {r for r, _ in robots}
            case lc.RobotDone(robot):
                self.done[rid].add(robot)
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
                self.claimed[rid] |= set(pick)  # as the shell claims what it chose
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
            attempt = life.attempt
            reserving = (
                {m.robot for m in attempt.chosen}
                if attempt is not None and attempt.stage == "reserving"
                else set()
            )
            assert self.claimed[rid] <= reserving, (
                f"robots {self.claimed[rid] - reserving} stay claimed by {rid}, which no "
                "longer needs them"
            )
            followed = {m.robot for m in life.followed()}
            ended = self.commanded[rid] - followed - self.done[rid]
            assert ended <= self.told[rid], (
                f"robots {ended - self.told[rid]} were sent for {rid} and their part ended "
                "without a stop"
            )
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
            progress = data.draw(st.sampled_from([0.2, 0.5, 0.8]))
            event = lc.RobotReport(robot, status, 50.0, phase, progress, last)
        elif kind == "tick":
            # Up to 20 s at once: silence (5 s), stalls (30 s), overruns (10 + 30 s).
            step = data.draw(st.floats(0.1, 20.0))
            world.now = lc.Now(world.now.mono + step, world.now.wall + step)
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


def test_a_robot_heard_again_after_a_silence_is_reminded_of_its_task() -> None:
    """A restarted gateway keeps an AGV's order only if the IaaS assigns it again."""
    life = SITUATIONS["underway"]  # a-1 heard at mono 100
    travel = lc.RobotReport("a-1", "busy", 80.0, "travel", 0.5)
    _, effects = lc.decide(life, travel, lc.Now(101.0, 1001.0))
    assert not any(isinstance(e, lc.Remind) for e in effects), "no silence: no reminder"
    _, effects = lc.decide(life, travel, lc.Now(103.0, 1003.0))  # 3 s silent, back on the task
    remind = _effect(effects, lc.Remind)
    assert isinstance(remind, lc.Remind)
    assert [m.robot for m in remind.members] == ["a-1"] and remind.task == TASK
