"""A stand-in IaaS that drives one robot through the rules of docs/protocol.md.

Why one long file: ``RobotCheck`` is one run against one robot, and its
scenarios share that run (the robot's session, its clock, what it has said
so far) in the order docs/protocol.md tells them; the transport and the rules
are apart already (``transport.py``, ``rules.py``).

The kit does what an IaaS does, on the same keys and with the same deadline
(``transport.py``), and checks what the robot answers and publishes against
the rules (``rules.py``)::

    join, state-schema, state-rate, battery-percent   (watched over the whole run)
    idle -> assign -> repeat-assign -> refuse-busy -> done -> overrun -> progress
         -> last-task -> cancel-after-finish
    cancel -> malformed-command -> late-ack -> reconnect -> hold

Each scenario after ``idle`` starts from a clean robot: a task left over is
cancelled and the robot must report idle within ``Timing.clean_within``, so one
failure does not show up again, misnamed, in the rules after it (they say
"not checked" and why). ``done`` waits for the task's expected time plus the
IaaS watchdog's tolerance (the larger of 50 % and 30 s); a robot still on it
then is stopped as the watchdog stops it (``overrun``), and must obey.

Each rule gives one ``Result``: passed or not, with one sentence; a failure
says what the robot did and which section of docs/protocol.md says otherwise.
A rule that could not be checked has failed, and its sentence says why.
"""

from __future__ import annotations

import itertools
import logging
import math
import secrets
import time
from collections.abc import Callable
from typing import TypeVar

from robocloud.conformance.rules import (
    AT_LOCATION,
    LATE_GRACE,
    PHASE_ORDER,
    RATE_SLACK,
    RECONNECT_TRAVEL,
    RULES,
    Failed,
    Result,
    Timing,
    cite,
    describe,
    ended,
    finished_phase,
    idle,
    location,
    malformed,
    phase_of,
    tolerance,
    where,
    working,
    working_on,
    xy,
)
from robocloud.conformance.transport import Heard, Sent, Transport
from robocloud.fleet import keys
from robocloud.fleet.messages import Assign, Cancel, Start, State

log = logging.getLogger(__name__)
T = TypeVar("T")

ROUTED_WITHIN = 2.0  # seconds for the robot's queryable to reach the kit once it is heard

__all__ = ["RULES", "Result", "RobotCheck", "Timing"]


class RobotCheck:
    """Drive robot ``robot`` of ``cloud`` through every rule; ``run()`` gives the results."""

    def __init__(
        self,
        endpoint: str,
        cloud: str,
        robot: str,
        *,
        client: bool = False,
        timing: Timing | None = None,
        capability: str | None = None,
        progress: Callable[[str], None] = lambda line: None,
    ) -> None:
        self.endpoint = endpoint
        self.cloud = keys.check_chunk(cloud, "cloud")
        self.robot = keys.check_chunk(robot, "robot")
        self.timing = timing = timing if timing is not None else Timing()
        self.ack_timeout = timing.ack_timeout
        self.capability = capability
        self.say = progress
        self.run_id = secrets.token_hex(3)
        self.io = Transport(
            endpoint,
            self.cloud,
            self.robot,
            client=client,
            reply_timeout=timing.ack_timeout + LATE_GRACE,
        )
        self._gaps: list[tuple[float, float]] = []  # (from, to): outages the kit made
        self._results: dict[str, Result] = {}
        self._requests = 0

    # -- the run ------------------------------------------------------------------

    def run(self) -> list[Result]:
        self.io.start = time.monotonic()
        self.io.open()
        try:
            self._steps()
        finally:
            self.io.close()
        self._watched_rules()
        return [
            self._results.get(rule, Result(rule, False, "not checked: an earlier rule failed."))
            for rule in RULES
        ]

    def _steps(self) -> None:
        if self._rule("join", self._join) is None:
            return
        start = self._rule("idle", self._idle_at_start)
        if start is None:
            return
        capability, target, expected, _ = start
        assign = self._rule("assign", lambda: self._assign(target, capability))
        if assign is not None:
            rid, acked_at, _ = assign
            self._rule("repeat-assign", lambda: self._repeat(rid, target, capability))
            self._rule("refuse-busy", lambda: self._refuse_busy(rid, target, capability))
            end = self._rule("done", lambda: self._done(rid, target, expected, acked_at))
            self._rule("overrun", lambda: self._overrun(rid, expected))
            self._rule("progress", lambda: self._progress(rid, acked_at, target))
            if end is not None:
                self._rule("last-task", lambda: self._last_task(rid, end[0]))
                self._rule("cancel-after-finish", lambda: self._cancel_after_finish(rid))
        self._rule("cancel", lambda: self._cancel(capability), clean=True)
        self._rule("malformed-command", lambda: self._malformed(capability), clean=True)
        self._rule("late-ack", lambda: self._cancel_at_once(capability), clean=True)
        self._rule("reconnect", lambda: self._reconnect(capability), clean=True)
        self._rule("hold", lambda: self._hold(capability), clean=True)

    def _rule(self, rule: str, check: Callable[[], T], clean: bool = False) -> T | None:
        """Run one rule's check: its value when it passed, None when it failed."""
        self.say(f"checking {rule}: {RULES[rule].what}")
        try:
            if clean:
                self._clean()
            value = check()
        except Failed as failure:
            self._results[rule] = Result(rule, False, cite(str(failure), rule))
            return None
        sentence = value[-1] if isinstance(value, tuple) else value
        self._results[rule] = Result(rule, True, str(sentence))
        return value

    def _clean(self) -> None:
        """Bring the robot back to idle, as the IaaS would: cancel whatever it still works on."""
        latest = self.io.latest()
        rid = working(latest) if latest is not None else None
        if rid is not None:
            self._command(Cancel(request_id=rid)).answered.wait(self.ack_timeout)
        elif latest is not None and idle(latest):
            return
        within = self.timing.clean_within
        heard = self.io.wait_state(idle, within, self.io.now() - 0.01)
        if heard is None:
            told = f"the kit cancelled {rid}, as the IaaS does when a request no longer needs "
            told += "the robot, and " if rid else ""
            raise Failed(
                f"not checked: {told}the robot did not become idle within {within:g} s "
                f"(it reported {describe(self.io.latest())}); after a cancel a robot stops "
                "where it is and reports status idle with task null"
            )

    # -- commands -------------------------------------------------------------------

    def _command(self, command: Assign | Cancel | Start) -> Sent:
        try:
            return self.io.command(command)
        except RuntimeError as error:
            raise Failed(f"{error}.") from None

    def _ask(self, command: Assign | Cancel | Start) -> Sent:
        """Send ``command`` and wait for its ack as the IaaS does.

        An ack later than the deadline counts as a refusal: the kit sends a
        cancel at once (as the IaaS does) and then still listens a little, to
        say how late the robot was.
        """
        sent = self._command(command)
        if not sent.answered.wait(self.ack_timeout):
            if isinstance(command, Assign):
                self._command(Cancel(request_id=command.request_id))
            sent.answered.wait(LATE_GRACE)
            raise Failed(self._late(sent))
        if sent.problem is not None:
            raise Failed(sent.problem)
        return sent

    def _late(self, sent: Sent) -> str:
        if sent.latency is None:
            return (
                f"the robot did not answer {sent.what} within {self.ack_timeout + LATE_GRACE:g} s; "
                f"the IaaS waits {self.ack_timeout:g} s (--ack-timeout) for an ack."
            )
        return (
            f"the robot answered {sent.what} after {sent.latency:.1f} s; the IaaS waits "
            f"{self.ack_timeout:g} s (--ack-timeout), counts a later answer as a refusal and "
            "sends a cancel."
        )

    def _request(self) -> str:
        self._requests += 1
        return f"check-{self.run_id}-{self._requests}"

    def _idle_state(self) -> State:
        state = self.io.latest()
        if state is None:
            raise Failed("no valid state was heard.")
        return state

    # -- the rules ----------------------------------------------------------------

    def _join(self) -> tuple[State, str]:
        heard = self.io.wait_heard(self.timing.join_timeout)
        if not heard:
            raise Failed(
                f"no state on {keys.state_key(self.cloud, self.robot)} within "
                f"{self.timing.join_timeout:g} s: is the robot connected to {self.endpoint}, "
                f"with cloud {self.cloud} and id {self.robot}?"
            )
        valid = self.io.wait_state(lambda state: True, self.timing.join_timeout, 0.0)
        if valid is None or valid.state is None:
            raise Failed(
                f"{len(self.io.all_heard())} messages came on the state key, none of them a valid "
                "state (see state-schema)."
            )
        self.io.wait_routed(ROUTED_WITHIN)  # else the assign tells what went wrong
        return valid.state, f"first state {heard[0].at:.1f} s into the check."

    def _idle_at_start(self) -> tuple[str, list[float], float, str]:
        state = self.io.latest()  # as it is now (join has heard it), else the next idle one
        if state is None or not idle(state):
            heard = self.io.wait_state(idle, 10.0, self.io.now() - 0.01)
            if heard is None or heard.state is None:
                raise Failed(
                    "the robot did not become idle within 10 s "
                    f"(it reported {describe(self.io.latest())})."
                )
            state = heard.state
        capabilities = state.capabilities
        if not capabilities:
            raise Failed("the robot has no capability, so no task can be given to it.")
        if self.capability is not None:
            if self.capability not in capabilities:
                raise Failed(f"the robot has no capability {self.capability}.")
            name = self.capability
        else:
            name = min(capabilities, key=lambda n: (capabilities[n].time, n))
        target = location(state, state.speed * self.timing.travel)
        expected = self.timing.travel + capabilities[name].time
        return (
            name,
            target,
            expected,
            f"idle at {xy(state.position)}; the kit uses its capability {name} "
            f"({capabilities[name].time:g} s).",
        )

    def _assign(self, target: list[float], capability: str) -> tuple[str, float, str]:
        rid = self._request()
        sent = self._ask(Assign(request_id=rid, location=target, capabilities=[capability]))
        assert sent.ack is not None and sent.latency is not None
        if not sent.ack.ok:
            raise Failed(f"the robot refused {sent.what}: {sent.ack.error or 'no reason given'}")
        acked = self.io.now()
        sent_at = sent.at - self.io.start
        within = self.timing.report_within
        heard = self.io.wait_state(lambda s: working_on(s, rid), within, sent_at)
        if heard is None:
            raise Failed(
                f"the robot acknowledged {sent.what} but no state showed it working on it "
                f"within {within:g} s (a robot publishes at once on every change)."
            )
        return (
            rid,
            acked,
            f"acknowledged ok in {sent.latency:.2f} s, reported working "
            f"{max(0.0, heard.at - sent_at):.2f} s after it was sent.",
        )

    def _still_on(self, rid: str, rule: str) -> None:
        """The robot still works on ``rid``: a rule that needs it busy can be checked."""
        latest = self.io.latest()
        if latest is None or not working_on(latest, rid):
            raise Failed(
                f"{rid} was over before the kit could check {rule}; choose a slower capability "
                "with --capability."
            )

    def _repeat(self, rid: str, target: list[float], capability: str) -> str:
        self._still_on(rid, "a repeated assign")
        sent = self._ask(Assign(request_id=rid, location=target, capabilities=[capability]))
        assert sent.ack is not None
        if not sent.ack.ok:
            raise Failed(
                f"the robot refused the repeated assign of {rid}: "
                f"{sent.ack.error or 'no reason given'}; repeating an assign is harmless."
            )
        return "acknowledged ok again."

    def _refuse_busy(self, rid: str, target: list[float], capability: str) -> str:
        self._still_on(rid, "a refusal while busy")
        other = self._request()
        sent = self._ask(Assign(request_id=other, location=target, capabilities=[capability]))
        assert sent.ack is not None
        if sent.ack.ok:
            self._command(Cancel(request_id=other))
            raise Failed(
                f"the robot took {other} while busy with {rid}; it must refuse (ok false, "
                "with a sentence) a request while on another."
            )
        if not sent.ack.error:
            raise Failed(f"the robot refused {other} without a sentence in error.")
        latest = self.io.latest()
        if latest is not None and not working_on(latest, rid) and not ended(latest, rid):
            raise Failed(f"after refusing {other} the robot no longer reports {rid}.")
        return f'refused: "{sent.ack.error}"'

    def _allowed(self, expected: float) -> float:
        return expected + tolerance(expected, self.timing.overrun_min)

    def _done(
        self, rid: str, target: list[float], expected: float, since: float
    ) -> tuple[float, str]:
        timeout = min(self.timing.task_timeout, self._allowed(expected))
        left = max(0.0, since + timeout - self.io.now())
        heard = self.io.wait_state(lambda s: ended(s, rid), left, 0.0)
        if heard is None or heard.state is None:
            raise Failed(
                f"{rid} did not end within {timeout:g} s (the task needs about {expected:g} s; "
                f"the IaaS's watchdog stops a robot past {self._allowed(expected):g} s); the "
                f"robot reported {describe(self.io.latest())}."
            )
        state = heard.state
        phase = finished_phase(state, rid)
        if phase != "done":
            raise Failed(f"{rid} ended {phase}, not done.")
        if state.status != "idle":
            heard_idle = self.io.wait_state(
                lambda s: s.status == "idle", self.timing.report_within, heard.at
            )
            if heard_idle is None:
                raise Failed(f"after finishing {rid} the robot is {state.status}, not idle.")
        off = math.dist(state.position, target)
        if off > AT_LOCATION:
            raise Failed(
                f"the robot finished {rid} {off:.1f} m from the task's location "
                f"(at most {AT_LOCATION:g} m)."
            )
        return heard.at, f"done {heard.at:.1f} s into the check, idle at the location."

    def _overrun(self, rid: str, expected: float) -> str:
        """A robot still on ``rid`` past its allowance is stopped, as the IaaS's watchdog does."""
        latest = self.io.latest()
        if latest is None or not working_on(latest, rid):
            return "the task ended in time: no stop was needed."
        allowed = self._allowed(expected)
        stop = self._ask(Cancel(request_id=rid))
        assert stop.ack is not None
        if not stop.ack.ok:
            raise Failed(
                f"the robot was still on {rid} past its expected finish ({expected:g} s, "
                f"{allowed:g} s with the watchdog's tolerance) and refused the stop: "
                f"{stop.ack.error}"
            )
        self._must_stop(
            rid,
            stop,
            f"the robot was still on {rid} past its expected finish ({expected:g} s, "
            f"{allowed:g} s with the watchdog's tolerance) and the kit stopped it, as the "
            "IaaS's watchdog does; ",
        )
        return f"still on {rid} past {allowed:g} s (see done), it obeyed the stop."

    def _progress(self, rid: str, since: float, target: list[float]) -> str:
        reports = [
            h.state
            for h in self.io.states(since - self.timing.report_within)
            if h.state is not None and h.state.task is not None and h.state.task.request_id == rid
        ]
        if not reports:
            raise Failed(f"no state reported {rid} in task.")
        last_phase, last_progress = -1, -1.0
        start = math.dist(reports[0].position, target)
        for state in reports:
            assert state.task is not None
            order = PHASE_ORDER[state.task.phase]
            if order < last_phase:
                raise Failed(f"{rid} went back to phase {state.task.phase}.")
            if state.task.progress < last_progress - 1e-9:
                raise Failed(
                    f"the progress of {rid} went back from {last_progress:.3f} "
                    f"to {state.task.progress:.3f}."
                )
            last_phase, last_progress = order, state.task.progress
        if math.dist(reports[-1].position, target) > start + 1e-6:
            raise Failed(f"the robot moved away from the location of {rid}.")
        phases = sorted({s.task.phase for s in reports if s.task}, key=PHASE_ORDER.__getitem__)
        return f"{len(reports)} reports, phases {' -> '.join(phases)}."

    def _last_task(self, rid: str, ended_at: float) -> str:
        linger = self.timing.linger
        until = max(ended_at, self.io.now()) + linger
        time.sleep(max(0.0, until - self.io.now()))
        states = [h for h in self.io.states(ended_at) if h.state is not None]
        for heard in states:
            assert heard.state is not None
            if not _keeps_done(heard, rid):
                last = heard.state.last_task
                raise Failed(
                    f"{heard.at - ended_at:.1f} s after finishing {rid} the robot's last_task "
                    f"was {last.request_id + ' ' + last.phase if last else 'null'}; a robot keeps "
                    "its last finished task in last_task until it is given another, so an IaaS "
                    "that was down learns how it ended."
                )
        return f"kept in {len(states)} states over {linger:g} s."

    def _cancel_after_finish(self, rid: str) -> str:
        """A cancel that crossed the robot's done: ok, and the done task stays in last_task."""
        told = self.io.now()
        sent = self._ask(Cancel(request_id=rid))
        assert sent.ack is not None
        if not sent.ack.ok:
            raise Failed(
                f"the robot refused the cancel of {rid}, which it had finished: "
                f"{sent.ack.error}; a robot with no task answers a cancel ok (nothing to stop)."
            )
        time.sleep(self.timing.watch)
        for heard in self.io.states(told):
            assert heard.state is not None
            if not idle(heard.state) or not _keeps_done(heard, rid):
                raise Failed(
                    f"after a cancel of {rid}, which it had finished, the robot reported "
                    f"{describe(heard.state)} with last_task {_last(heard.state)}; a cancel after "
                    "the end changes nothing: the robot stays idle and last_task keeps the done "
                    "task until the next assign."
                )
        return "ok; idle, last_task still done."

    def _cancel(self, capability: str) -> str:
        state = self._idle_state()
        rid = self._request()
        target = location(state, state.speed * self.timing.travel)
        sent = self._ask(Assign(request_id=rid, location=target, capabilities=[capability]))
        assert sent.ack is not None
        if not sent.ack.ok:
            raise Failed(f"the robot refused {sent.what}: {sent.ack.error}")
        self._reported(rid)
        stop = self._ask(Cancel(request_id=rid))
        assert stop.ack is not None
        if not stop.ack.ok:
            raise Failed(f"the robot refused the cancel of {rid}: {stop.ack.error}")
        self._must_stop(rid, stop)
        again = self._ask(Cancel(request_id=rid))
        assert again.ack is not None
        if not again.ack.ok:
            raise Failed(
                f"the robot refused a second cancel of {rid}: {again.ack.error}; cancelling a "
                "request the robot no longer has is harmless (ok)."
            )
        return "acknowledged, stopped and idle; a second cancel was ok too."

    def _hold(self, capability: str) -> str:
        """Protocol 1.2: driven to the place, held there (phase waiting) until its start."""
        state = self._idle_state()
        if not state.holds:
            return (
                "not for this robot: its state says no protocol 1.2, so an IaaS never sends "
                "it hold or start."
            )
        rid = self._request()
        target = location(state, state.speed * self.timing.travel)
        go = Assign(request_id=rid, location=target, capabilities=[capability], hold=True)
        sent = self._ask(go)
        assert sent.ack is not None
        if not sent.ack.ok:
            raise Failed(f"the robot refused {sent.what} with hold: {sent.ack.error}")
        self._reported(rid)
        travel = self._allowed(self.timing.travel)
        there = self.io.wait_state(
            lambda s: phase_of(s, rid) == "waiting", travel, sent.at - self.io.start
        )
        if there is None or there.state is None:
            raise Failed(
                f"{rid} was sent with hold, but the robot did not report phase waiting within "
                f"{travel:g} s (it reported {describe(self.io.latest())}); a robot of protocol "
                "1.2 drives to the location, then reports waiting until its start."
            )
        off = math.dist(there.state.position, target)
        if off > AT_LOCATION:
            raise Failed(
                f"the robot reported waiting for {rid} {off:.1f} m from the task's location "
                f"(at most {AT_LOCATION:g} m): it waits at the place, not on the way."
            )
        time.sleep(self.timing.watch)
        held = there.state.task.progress if there.state.task is not None else 0.0
        for later in self.io.states(there.at):
            assert later.state is not None
            task = later.state.task
            if phase_of(later.state, rid) != "waiting" or (task and task.progress > held + 1e-9):
                raise Failed(
                    f"the robot was held at {rid}'s location but reported "
                    f"{describe(later.state)} before any start; a held task waits, its "
                    "progress still, until its start."
                )
        other = self._ask(Start(request_id=self._request()))
        assert other.ack is not None
        if other.ack.ok:
            raise Failed(
                f"the robot acknowledged {other.what} ok, a request it does not hold; a start "
                "for another request, or with no task, is refused with a sentence."
            )
        start = self._ask(Start(request_id=rid))
        assert start.ack is not None
        if not start.ack.ok:
            raise Failed(f"the robot refused the start of {rid}, which it held: {start.ack.error}")
        told = start.at - self.io.start
        working = self.io.wait_state(
            lambda s: phase_of(s, rid) in ("work", "done"), self.timing.report_within, told
        )
        if working is None:
            raise Failed(
                f"the robot acknowledged the start of {rid} but no state showed it working "
                f"within {self.timing.report_within:g} s."
            )
        work = state.capabilities[capability].time
        end = self.io.wait_state(lambda s: ended(s, rid), self._allowed(work), told)
        if end is None or end.state is None or finished_phase(end.state, rid) != "done":
            raise Failed(
                f"after its start {rid} did not end done within {self._allowed(work):g} s "
                f"(the work takes about {work:g} s); the robot reported "
                f"{describe(self.io.latest())}."
            )
        return (
            f"waited at the location for its start ({self.timing.watch:g} s watched), refused "
            f"another request's start, worked on its own and was done {end.at - told:.1f} s "
            "later."
        )

    def _reported(self, rid: str) -> None:
        if self.io.wait_state(lambda s: working_on(s, rid), self.timing.report_within, 0.0) is None:
            raise Failed(f"the robot took {rid} but never reported working on it.")

    def _must_stop(self, rid: str, stop: Sent, context: str = "") -> None:
        """The robot stops working on ``rid`` within ``report_within`` of the cancel, and stays.

        Counted from when the cancel was sent, not from its ack: a robot publishes
        the change at once, and that state may come before its ack, or before the
        kit has read the ack; the robot's next state may then be a second away.
        """
        told = stop.at - self.io.start
        within = self.timing.report_within
        heard = self.io.wait_state(lambda s: not working_on(s, rid), within, told)
        if heard is None:
            did = f"still reported it {within:g} s later"
            if not self.io.states(told):
                did = f"sent no state within {within:g} s"
            raise Failed(
                f"{context}the robot acknowledged the cancel of {rid} but {did}; after a cancel "
                "a robot stops where it is and reports status idle and no task, at once."
            )
        time.sleep(self.timing.watch)
        for later in self.io.states(heard.at):
            if later.state is not None and working_on(later.state, rid):
                raise Failed(
                    f"{context}the robot reported {rid} again {later.at - told:.1f} s after its "
                    "cancel; a canceled task must not come back."
                )
        if heard.state is not None and heard.state.status != "idle":
            raise Failed(
                f"{context}after the cancel of {rid} the robot is {heard.state.status}, not idle."
            )

    def _malformed(self, capability: str) -> str:
        """Commands that are not valid: an ack each (ok false, a sentence), and nothing done."""
        rid = self._request()
        since = self.io.now()
        errors: list[str] = []
        for what, payload in malformed(rid, capability):
            try:
                sent = self.io.send(payload, what, rid)
            except RuntimeError as error:
                raise Failed(f"{error}.") from None
            if not sent.answered.wait(self.ack_timeout):
                raise Failed(
                    f"the robot did not answer {what} within {self.ack_timeout:g} s; a robot "
                    "answers every command with one Ack: ok false with a sentence in error when "
                    "it cannot read it."
                )
            if sent.problem is not None:
                raise Failed(sent.problem)
            assert sent.ack is not None
            if sent.ack.ok:
                self._command(Cancel(request_id=rid))
                raise Failed(
                    f"the robot answered {what} with ok true; a command that is not valid gets "
                    "ok false with a sentence in error, and the robot does nothing."
                )
            if not sent.ack.error:
                raise Failed(f"the robot refused {what} without a sentence in error.")
            errors.append(sent.ack.error)
        time.sleep(self.timing.watch)
        for heard in self.io.states(since):
            if heard.state is not None and working_on(heard.state, rid):
                raise Failed(f"after refusing a malformed command the robot worked on {rid}.")
        return f'{len(errors)} malformed commands refused, e.g. "{errors[-1]}"'

    def _cancel_at_once(self, capability: str) -> str:
        """The IaaS's side of a late ack: a cancel right behind the assign must win.

        Whether every ack came in time is judged at the end, over the whole run.
        """
        state = self._idle_state()
        rid = self._request()
        target = location(state, state.speed * self.timing.travel)
        assign = self._command(Assign(request_id=rid, location=target, capabilities=[capability]))
        cancel = self._command(Cancel(request_id=rid))  # the IaaS counted its ack as late
        assign.answered.wait(self.ack_timeout)
        cancel.answered.wait(self.ack_timeout)
        time.sleep(self.timing.watch)
        latest = self.io.latest()
        if latest is not None and working_on(latest, rid):
            raise Failed(
                f"a cancel sent right behind the assign of {rid} left the robot working on it; "
                "when an ack is late the IaaS sends a cancel at once, and the robot must obey it."
            )
        return "a cancel right behind an assign was obeyed"

    def _slowest(self) -> float:
        return max((s.latency for s in self.io.sent if s.latency is not None), default=0.0)

    def _reconnect(self, capability: str) -> str:
        state = self._idle_state()
        rid = self._request()
        target = location(state, state.speed * RECONNECT_TRAVEL)
        sent = self._ask(Assign(request_id=rid, location=target, capabilities=[capability]))
        assert sent.ack is not None
        if not sent.ack.ok:
            raise Failed(f"the robot refused {sent.what}: {sent.ack.error}")
        self._reported(rid)
        went = self.io.now()
        self.say(f"closing the kit's Zenoh session for {self.timing.outage:g} s")
        self.io.close()
        time.sleep(self.timing.outage)
        self.io.open()
        back = self.io.now()
        self._gaps.append((went, back))
        heard = self.io.wait_state(lambda s: True, self.timing.reconnect_timeout, back)
        if heard is None or heard.state is None:
            raise Failed(
                f"no state within {self.timing.reconnect_timeout:g} s after the kit came back; a "
                "robot reconnects by itself (a Zenoh client does) and keeps publishing."
            )
        after = heard.state
        took = heard.at - back
        if working_on(after, rid):
            self.io.wait_routed(ROUTED_WITHIN)  # else the cancel tells what went wrong
            stop = self._ask(Cancel(request_id=rid))  # the request is over for this "IaaS"
            assert stop.ack is not None
            if not stop.ack.ok:
                raise Failed(f"after reconnecting, the robot refused the cancel of {rid}.")
            self._must_stop(rid, stop)
            return f"back {took:.1f} s after the outage still on {rid}; stopped when told."
        if finished_phase(after, rid) == "done":
            return f"back {took:.1f} s after the outage; {rid} had finished (last_task)."
        raise Failed(
            f"after the outage the robot reported {describe(after)}, not {rid}: a robot keeps its "
            "task (or, once finished, its last_task) across a lost connection, and stops only "
            "when told."
        )

    # -- rules over every state -------------------------------------------------------

    def _watched_rules(self) -> None:
        heard = self.io.all_heard()
        if not heard:
            for rule in ("state-schema", "state-rate", "battery-percent"):
                self._results[rule] = Result(rule, False, "not checked: no state was heard.")
            return
        refused = [h for h in heard if h.state is None]
        if refused:
            self._results["state-schema"] = Result(
                "state-schema",
                False,
                f"{len(refused)} of {len(heard)} states were refused; the first: "
                f"{refused[0].problem} The schemas of docs/protocol/ are the contract "
                f"({where('state-schema')}).",
            )
        else:
            self._results["state-schema"] = Result(
                "state-schema", True, f"{len(heard)} states, all valid."
            )
        self._results["state-rate"] = self._rate(heard)
        self._results["battery-percent"] = self._battery(heard)
        self._acks_in_time()

    def _acks_in_time(self) -> None:
        """late-ack: besides the cancel right behind an assign, every ack of the run in time."""
        result = self._results.get("late-ack")
        sent = self.io.sent
        late = [s for s in sent if s.latency is None or s.latency > self.ack_timeout]
        if late:
            self._results["late-ack"] = Result(
                "late-ack", False, cite(self._late(late[0]), "late-ack")
            )
        elif result is not None and result.passed:
            result.sentence += (
                f"; all {len(sent)} acks in time, the slowest in {self._slowest():.2f} s."
            )

    def _rate(self, heard: list[Heard]) -> Result:
        valid = [h for h in heard if h.state is not None]
        if len(valid) < 2:
            return Result("state-rate", False, "fewer than two valid states were heard.")
        worst, worst_at = 0.0, 0.0
        for before, after in itertools.pairwise(valid):
            if any(before.at <= gap_to and after.at >= gap_from for gap_from, gap_to in self._gaps):
                continue  # the kit itself was away
            if after.at - before.at > worst:
                worst, worst_at = after.at - before.at, before.at
        if worst > 1.0 + RATE_SLACK:
            return Result(
                "state-rate",
                False,
                f"the robot went {worst:.1f} s without a state ({worst_at:.1f} s into the check); "
                "a robot publishes at least once a second (the IaaS counts it offline after 5 s) "
                f"({where('state-rate')}).",
            )
        for before, after in itertools.pairwise(valid):
            assert before.state is not None and after.state is not None
            if after.state.seq <= before.state.seq:
                return Result(
                    "state-rate",
                    False,
                    f"seq went from {before.state.seq} to {after.state.seq} "
                    f"({after.at:.1f} s into the check); it increases with every state "
                    f"({where('state-rate')}).",
                )
        return Result("state-rate", True, f"the longest silence was {worst:.2f} s.")

    def _battery(self, heard: list[Heard]) -> Result:
        batteries = [h.state.battery for h in heard if h.state is not None]
        if not batteries:
            return Result("battery-percent", False, "not checked: no valid state was heard.")
        top = max(batteries)
        if 0.0 < top <= 1.0:
            return Result(
                "battery-percent",
                False,
                f"battery was at most {top:g}: battery is a percent from 0 to 100, so this is "
                f"{top:g} % (a fraction such as ROS's BatteryState.percentage must be multiplied "
                "by 100); if the robot is truly this low, charge it and check again "
                f"({where('battery-percent')}).",
            )
        return Result("battery-percent", True, f"{min(batteries):g} to {top:g} %.")


def _keeps_done(heard: Heard, rid: str) -> bool:
    last = heard.state.last_task if heard.state is not None else None
    return last is not None and last.request_id == rid and last.phase == "done"


def _last(state: State | None) -> str:
    last = state.last_task if state is not None else None
    return f"{last.request_id} {last.phase}" if last is not None else "null"
