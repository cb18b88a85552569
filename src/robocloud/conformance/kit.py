"""A stand-in IaaS that drives one robot through the rules of docs/protocol.md.

The kit does what an IaaS does, on the same keys and with the same deadline,
and checks what the robot answers and publishes::

    join, state-schema, state-rate, battery-percent   (watched over the whole run)
    idle -> assign -> repeat-assign -> refuse-busy -> progress -> done -> last-task
    cancel -> late-ack -> reconnect

By default it is a Zenoh router listening on the endpoint the robot connects
to, as ``robocloud iaas --zenoh`` is; for ``reconnect`` it closes the router,
waits ``outage`` seconds and opens it again, as an IaaS that restarts. With
``client=True`` it connects as a Zenoh client to a router already there (the
robot's own, or a zenohd) and only its own session goes away and comes back.

Each rule gives one ``Result``: passed or not, with one sentence. A rule that
could not be checked (the robot never became idle, say) has failed, and its
sentence says why.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import math
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypeVar

import pydantic
import zenoh

from robocloud.domain.robot import MAX_COORDINATE
from robocloud.errors import describe_validation_errors
from robocloud.fleet import keys
from robocloud.fleet.messages import FINISHED_PHASES, Ack, Assign, Cancel, State
from robocloud.fleet.state_errors import StateErrors
from robocloud.fleet.zenoh_session import open_client, open_router

log = logging.getLogger(__name__)
T = TypeVar("T")

RULES: dict[str, str] = {
    "join": "the robot publishes its state on its key",
    "state-schema": "every state is valid and names the robot of its key",
    "state-rate": "a state at least once a second, seq increasing",
    "battery-percent": "battery is a percent from 0 to 100, not a fraction",
    "idle": "the robot starts idle, with a capability to use",
    "assign": "an assign is acknowledged ok in time and reported at once",
    "repeat-assign": "the same assign again is acknowledged ok",
    "refuse-busy": "an assign for another request while busy is refused with a sentence",
    "progress": "phases move forward, progress grows from 0 to 1, the robot nears the location",
    "done": "the task ends done, the robot idle at the location",
    "last-task": "the finished task stays in last_task until the next one",
    "cancel": "a cancel is acknowledged and the robot stops, idle, within a second",
    "late-ack": "every ack within the deadline; a cancel right after an assign is obeyed",
    "reconnect": "after an outage the robot reports its task again and obeys the cancel",
}
WORKING = frozenset({"travel", "work"})
PHASE_ORDER = {"travel": 0, "work": 1, "done": 2, "failed": 2}
REPORT_WITHIN = 1.0  # seconds from an ack to the state that shows the change
RATE_SLACK = 0.3  # seconds of jitter tolerated over "at least once a second"
LATE_GRACE = 3.0  # seconds the kit still listens for an ack past the deadline
LINGER = 4.0  # seconds the kit watches last_task after a task ended (past the 3 s a task stays)
TRAVEL = 2.0  # seconds of travel the kit's task asks for
RECONNECT_TRAVEL = 30.0  # seconds of travel of the task that spans the outage
AT_LOCATION = 1.0  # metres: how near the location "done" must be


@dataclass
class Result:
    rule: str
    passed: bool
    sentence: str


@dataclass
class Heard:
    at: float  # seconds since the check began
    state: State | None
    problem: str | None = None  # why the message was refused


@dataclass
class Sent:
    """One command and its ack."""

    command: Assign | Cancel
    at: float  # monotonic, when sent
    answered: threading.Event = field(default_factory=threading.Event)
    ack: Ack | None = None
    problem: str | None = None  # the reply was not an Ack of this robot
    latency: float | None = None

    @property
    def what(self) -> str:
        return f"the {self.command.type} of {self.command.request_id}"


class Failed(Exception):
    """A rule failed; the message is its sentence."""


class RobotCheck:
    """Drive robot ``robot`` of ``cloud`` through every rule; ``run()`` gives the results."""

    def __init__(
        self,
        endpoint: str,
        cloud: str,
        robot: str,
        *,
        client: bool = False,
        ack_timeout: float = 2.0,
        join_timeout: float = 15.0,
        task_timeout: float = 120.0,
        outage: float = 2.0,
        reconnect_timeout: float = 20.0,
        capability: str | None = None,
        progress: Callable[[str], None] = lambda line: None,
    ) -> None:
        self.endpoint = endpoint
        self.cloud = keys.check_chunk(cloud, "cloud")
        self.robot = keys.check_chunk(robot, "robot")
        self.client = client
        self.ack_timeout = ack_timeout
        self.join_timeout = join_timeout
        self.task_timeout = task_timeout
        self.outage = outage
        self.reconnect_timeout = reconnect_timeout
        self.capability = capability
        self.say = progress
        self.run_id = secrets.token_hex(3)
        self._session: zenoh.Session | None = None
        self._subscriber: zenoh.Subscriber[None] | None = None
        self._errors: StateErrors | None = None
        self._heard: list[Heard] = []
        self._gaps: list[tuple[float, float]] = []  # (from, to): outages the kit made
        self._changed = threading.Condition()
        self._sent: list[Sent] = []
        self._start = time.monotonic()
        self._results: dict[str, Result] = {}
        self._requests = 0

    # -- the run ------------------------------------------------------------------

    def run(self) -> list[Result]:
        self._start = time.monotonic()
        self._open()
        try:
            self._steps()
        finally:
            self._close()
        self._watched_rules()
        return [
            self._results.get(rule, Result(rule, False, "not checked: an earlier rule failed."))
            for rule in RULES
        ]

    def _steps(self) -> None:
        first = self._rule("join", self._join)
        if first is None:
            return
        start = self._rule("idle", self._idle_at_start)
        if start is None:
            return
        capability, location, expected, _ = start
        assign = self._rule("assign", lambda: self._assign(location, capability))
        if assign is not None:
            rid, acked_at, _ = assign
            self._rule("repeat-assign", lambda: self._repeat(rid, location, capability))
            self._rule("refuse-busy", lambda: self._refuse_busy(rid, location, capability))
            ended = self._rule("done", lambda: self._done(rid, location, expected))
            self._rule("progress", lambda: self._progress(rid, acked_at, location))
            if ended is not None:
                self._rule("last-task", lambda: self._last_task(rid, ended[0]))
        self._rule("cancel", lambda: self._cancel(capability))
        self._rule("late-ack", lambda: self._cancel_at_once(capability))
        self._rule("reconnect", lambda: self._reconnect(capability))

    def _rule(self, rule: str, check: Callable[[], T]) -> T | None:
        """Run one rule's check: its value when it passed, None when it failed."""
        self.say(f"checking {rule}: {RULES[rule]}")
        try:
            value = check()
        except Failed as failure:
            self._results[rule] = Result(rule, False, str(failure))
            return None
        sentence = value[-1] if isinstance(value, tuple) else value
        self._results[rule] = Result(rule, True, str(sentence))
        return value

    # -- Zenoh --------------------------------------------------------------------

    def _open(self) -> None:
        if self.client:
            session = open_client([self.endpoint], timeout=5.0)
        else:
            session = open_router([self.endpoint])
        self._session = session
        self._errors = StateErrors(session, self.cloud)
        self._subscriber = session.declare_subscriber(
            keys.state_key(self.cloud, self.robot), self._on_state
        )

    def _close(self) -> None:
        session, self._session = self._session, None
        if session is None:
            return
        with contextlib.suppress(zenoh.ZError):
            if self._subscriber is not None:
                self._subscriber.undeclare()  # type: ignore[no-untyped-call]
            session.close()  # type: ignore[no-untyped-call]

    def _on_state(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        at = self._now()
        key = str(sample.key_expr)
        state: State | None = None
        problem: str | None = None
        try:
            state = State.model_validate_json(sample.payload.to_bytes())
        except pydantic.ValidationError as error:
            problem = describe_validation_errors(error.errors()).message
            if self._errors is not None:
                self._errors.invalid(key, error)
        if state is not None and (state.id != self.robot or state.cloud != self.cloud):
            problem = f"it names robot {state.cloud}/{state.id}, not {self.cloud}/{self.robot}."
            if self._errors is not None:
                self._errors.mismatch(key, state)
            state = None
        with self._changed:
            self._heard.append(Heard(at, state, problem))
            self._changed.notify_all()

    def _now(self) -> float:
        return time.monotonic() - self._start

    def _command(self, command: Assign | Cancel) -> Sent:
        """Send ``command``; the Sent is answered in the background (``wait`` for it)."""
        sent = Sent(command, time.monotonic())
        self._sent.append(sent)

        def on_reply(reply: zenoh.Reply) -> None:
            if sent.answered.is_set():
                return
            sample = reply.ok
            if sample is None:
                error = reply.err
                detail = error.payload.to_string() if error is not None else ""
                if detail == "Timeout":
                    return  # Zenoh's own word that nobody answered in time
                sent.problem = f"the robot answered {sent.what} with an error: {detail}"
            else:
                sent.latency = time.monotonic() - sent.at
                try:
                    ack = Ack.model_validate_json(sample.payload.to_bytes())
                except pydantic.ValidationError as error:
                    described = describe_validation_errors(error.errors(), "ack").message
                    sent.problem = f"the reply to {sent.what} is not an Ack: {described}"
                else:
                    if ack.robot != self.robot:
                        sent.problem = f"the ack of {sent.what} names robot {ack.robot}."
                    elif ack.request_id not in (None, command.request_id):
                        sent.problem = (
                            f"the ack of {sent.what} names request {ack.request_id}."
                        )
                    sent.ack = ack
            sent.answered.set()

        if self._session is None:
            raise Failed("the kit's Zenoh session is closed.")
        self._session.get(
            keys.cmd_key(self.cloud, self.robot),
            on_reply,
            payload=command.model_dump_json(),
            encoding=zenoh.Encoding.APPLICATION_JSON,
            target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=self.ack_timeout + LATE_GRACE,
        )
        return sent

    def _ask(self, command: Assign | Cancel) -> Sent:
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

    # -- watching states ------------------------------------------------------------

    def _wait_state(
        self, test: Callable[[State], bool], timeout: float, since: float
    ) -> Heard | None:
        """The first valid state heard after ``since`` (seconds into the run) that passes."""
        deadline = time.monotonic() + timeout
        with self._changed:
            while True:
                for heard in self._heard:
                    if heard.at >= since and heard.state is not None and test(heard.state):
                        return heard
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._changed.wait(left)

    def _states(self, since: float, until: float = math.inf) -> list[Heard]:
        with self._changed:
            return [h for h in self._heard if since <= h.at <= until and h.state is not None]

    def _latest(self) -> State | None:
        with self._changed:
            for heard in reversed(self._heard):
                if heard.state is not None:
                    return heard.state
        return None

    def _wait_idle(self, timeout: float) -> State:
        heard = self._wait_state(idle, timeout, self._now() - 0.01)
        if heard is None or heard.state is None:
            latest = self._latest()
            doing = describe(latest) if latest is not None else "nothing valid"
            raise Failed(
                f"the robot did not become idle within {timeout:g} s (it reported {doing})."
            )
        return heard.state

    def _request(self) -> str:
        self._requests += 1
        return f"check-{self.run_id}-{self._requests}"

    # -- the rules ----------------------------------------------------------------

    def _join(self) -> tuple[State, str]:
        with self._changed:
            self._changed.wait_for(lambda: bool(self._heard), self.join_timeout)
            heard = list(self._heard)
        if not heard:
            raise Failed(
                f"no state on {keys.state_key(self.cloud, self.robot)} within "
                f"{self.join_timeout:g} s: is the robot connected to {self.endpoint}, with cloud "
                f"{self.cloud} and id {self.robot}?"
            )
        valid = self._wait_state(lambda state: True, self.join_timeout, 0.0)
        if valid is None or valid.state is None:
            raise Failed(
                f"{len(self._heard)} messages came on the state key, none of them a valid state "
                f"(see state-schema)."
            )
        time.sleep(0.3)  # the robot's queryable is routed with its publisher, give it a moment
        return valid.state, f"first state {heard[0].at:.1f} s into the check."

    def _idle_at_start(self) -> tuple[str, list[float], float, str]:
        state = self._wait_idle(10.0)
        capabilities = state.capabilities
        if not capabilities:
            raise Failed("the robot has no capability, so no task can be given to it.")
        if self.capability is not None:
            if self.capability not in capabilities:
                raise Failed(f"the robot has no capability {self.capability}.")
            name = self.capability
        else:
            name = min(capabilities, key=lambda n: (capabilities[n].time, n))
        location = _location(state, state.speed * TRAVEL)
        expected = TRAVEL + capabilities[name].time
        return (
            name,
            location,
            expected,
            f"idle at {_xy(state.position)}; the kit uses its capability {name} "
            f"({capabilities[name].time:g} s).",
        )

    def _assign(self, location: list[float], capability: str) -> tuple[str, float, str]:
        rid = self._request()
        sent = self._ask(Assign(request_id=rid, location=location, capabilities=[capability]))
        assert sent.ack is not None and sent.latency is not None
        if not sent.ack.ok:
            raise Failed(f"the robot refused {sent.what}: {sent.ack.error or 'no reason given'}")
        acked = self._now()
        sent_at = sent.at - self._start
        heard = self._wait_state(lambda s: working_on(s, rid), REPORT_WITHIN, sent_at)
        if heard is None:
            raise Failed(
                f"the robot acknowledged {sent.what} but no state showed it working on it "
                f"within {REPORT_WITHIN:g} s (a robot publishes at once on every change)."
            )
        return (
            rid,
            acked,
            f"acknowledged ok in {sent.latency:.2f} s, reported working "
            f"{max(0.0, heard.at - sent_at):.2f} s after it was sent.",
        )

    def _still_on(self, rid: str, rule: str) -> None:
        """The robot still works on ``rid``: a rule that needs it busy can be checked."""
        latest = self._latest()
        if latest is None or not working_on(latest, rid):
            raise Failed(
                f"{rid} was over before the kit could check {rule}; choose a slower capability "
                "with --capability."
            )

    def _repeat(self, rid: str, location: list[float], capability: str) -> str:
        self._still_on(rid, "a repeated assign")
        sent = self._ask(Assign(request_id=rid, location=location, capabilities=[capability]))
        assert sent.ack is not None
        if not sent.ack.ok:
            raise Failed(
                f"the robot refused the repeated assign of {rid}: "
                f"{sent.ack.error or 'no reason given'}; repeating an assign is harmless."
            )
        return "acknowledged ok again."

    def _refuse_busy(self, rid: str, location: list[float], capability: str) -> str:
        self._still_on(rid, "a refusal while busy")
        other = self._request()
        sent = self._ask(Assign(request_id=other, location=location, capabilities=[capability]))
        assert sent.ack is not None
        if sent.ack.ok:
            self._command(Cancel(request_id=other))
            raise Failed(
                f"the robot took {other} while busy with {rid}; it must refuse (ok false, "
                "with a sentence) a request while on another."
            )
        if not sent.ack.error:
            raise Failed(f"the robot refused {other} without a sentence in error.")
        latest = self._latest()
        if latest is not None and not working_on(latest, rid) and not ended(latest, rid):
            raise Failed(f"after refusing {other} the robot no longer reports {rid}.")
        return f'refused: "{sent.ack.error}"'

    def _done(self, rid: str, location: list[float], expected: float) -> tuple[float, str]:
        timeout = min(self.task_timeout, 3 * expected + 5.0)
        heard = self._wait_state(lambda s: ended(s, rid), timeout, 0.0)
        if heard is None or heard.state is None:
            latest = self._latest()
            raise Failed(
                f"{rid} did not end within {timeout:g} s (the task needs about "
                f"{expected:g} s); the robot reported {describe(latest) if latest else 'nothing'}."
            )
        state = heard.state
        phase = finished_phase(state, rid)
        if phase != "done":
            raise Failed(f"{rid} ended {phase}, not done.")
        if state.status != "idle":
            heard_idle = self._wait_state(lambda s: s.status == "idle", REPORT_WITHIN, heard.at)
            if heard_idle is None:
                raise Failed(f"after finishing {rid} the robot is {state.status}, not idle.")
        off = math.dist(state.position, location)
        if off > AT_LOCATION:
            raise Failed(
                f"the robot finished {rid} {off:.1f} m from the task's location "
                f"(at most {AT_LOCATION:g} m)."
            )
        return heard.at, f"done {heard.at:.1f} s into the check, idle at the location."

    def _progress(self, rid: str, since: float, location: list[float]) -> str:
        reports = [
            h.state
            for h in self._states(since - REPORT_WITHIN)
            if h.state is not None and h.state.task is not None and h.state.task.request_id == rid
        ]
        if not reports:
            raise Failed(f"no state reported {rid} in task.")
        last_phase, last_progress = -1, -1.0
        start = math.dist(reports[0].position, location)
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
        if math.dist(reports[-1].position, location) > start + 1e-6:
            raise Failed(f"the robot moved away from the location of {rid}.")
        phases = sorted({s.task.phase for s in reports if s.task}, key=PHASE_ORDER.__getitem__)
        return f"{len(reports)} reports, phases {' -> '.join(phases)}."

    def _last_task(self, rid: str, ended_at: float) -> str:
        until = max(ended_at, self._now()) + LINGER
        time.sleep(max(0.0, until - self._now()))
        states = [h for h in self._states(ended_at) if h.state is not None]
        for heard in states:
            assert heard.state is not None
            last = heard.state.last_task
            if last is None or last.request_id != rid or last.phase != "done":
                raise Failed(
                    f"{heard.at - ended_at:.1f} s after finishing {rid} the robot's last_task "
                    f"was {last.request_id + ' ' + last.phase if last else 'null'}; a robot keeps "
                    "its last finished task in last_task until it is given another, so an IaaS "
                    "that was down learns how it ended."
                )
        return f"kept in {len(states)} states over {LINGER:g} s."

    def _cancel(self, capability: str) -> str:
        state = self._wait_idle(self.task_timeout)
        rid = self._request()
        location = _location(state, state.speed * TRAVEL)
        sent = self._ask(Assign(request_id=rid, location=location, capabilities=[capability]))
        assert sent.ack is not None
        if not sent.ack.ok:
            raise Failed(f"the robot refused {sent.what}: {sent.ack.error}")
        if self._wait_state(lambda s: working_on(s, rid), REPORT_WITHIN, 0.0) is None:
            raise Failed(f"the robot took {rid} but never reported working on it.")
        stop = self._ask(Cancel(request_id=rid))
        assert stop.ack is not None
        if not stop.ack.ok:
            raise Failed(f"the robot refused the cancel of {rid}: {stop.ack.error}")
        self._must_stop(rid, self._now())
        again = self._ask(Cancel(request_id=rid))
        assert again.ack is not None
        if not again.ack.ok:
            raise Failed(
                f"the robot refused a second cancel of {rid}: {again.ack.error}; cancelling a "
                "request the robot no longer has is harmless (ok)."
            )
        return "acknowledged, stopped and idle; a second cancel was ok too."

    def _must_stop(self, rid: str, told: float) -> None:
        """The robot stops working on ``rid`` within a second of ``told``, and stays stopped."""
        heard = self._wait_state(lambda s: not working_on(s, rid), REPORT_WITHIN, told)
        if heard is None:
            raise Failed(
                f"the robot acknowledged the cancel of {rid} but still reported it "
                f"{REPORT_WITHIN:g} s later; after a cancel a robot stops where it is and "
                "reports status idle and no task."
            )
        time.sleep(1.0)
        for later in self._states(heard.at):
            if later.state is not None and working_on(later.state, rid):
                raise Failed(
                    f"the robot reported {rid} again {later.at - told:.1f} s after its cancel; "
                    "a canceled task must not come back."
                )
        if heard.state is not None and heard.state.status != "idle":
            raise Failed(f"after the cancel of {rid} the robot is {heard.state.status}, not idle.")

    def _cancel_at_once(self, capability: str) -> str:
        """The IaaS's side of a late ack: a cancel right behind the assign must win.

        Whether every ack came in time is judged at the end, over the whole run.
        """
        state = self._wait_idle(self.task_timeout)
        rid = self._request()
        location = _location(state, state.speed * TRAVEL)
        assign = self._command(Assign(request_id=rid, location=location, capabilities=[capability]))
        cancel = self._command(Cancel(request_id=rid))  # the IaaS counted its ack as late
        assign.answered.wait(self.ack_timeout)
        cancel.answered.wait(self.ack_timeout)
        time.sleep(REPORT_WITHIN)
        latest = self._latest()
        if latest is not None and working_on(latest, rid):
            raise Failed(
                f"a cancel sent right behind the assign of {rid} left the robot working on it; "
                "when an ack is late the IaaS sends a cancel at once, and the robot must obey it."
            )
        return "a cancel right behind an assign was obeyed"

    def _slowest(self) -> float:
        return max((s.latency for s in self._sent if s.latency is not None), default=0.0)

    def _reconnect(self, capability: str) -> str:
        state = self._wait_idle(self.task_timeout)
        rid = self._request()
        location = _location(state, state.speed * RECONNECT_TRAVEL)
        sent = self._ask(Assign(request_id=rid, location=location, capabilities=[capability]))
        assert sent.ack is not None
        if not sent.ack.ok:
            raise Failed(f"the robot refused {sent.what}: {sent.ack.error}")
        if self._wait_state(lambda s: working_on(s, rid), REPORT_WITHIN, 0.0) is None:
            raise Failed(f"the robot took {rid} but never reported working on it.")
        went = self._now()
        self.say(f"closing the kit's Zenoh session for {self.outage:g} s")
        self._close()
        time.sleep(self.outage)
        self._open()
        back = self._now()
        self._gaps.append((went, back))
        heard = self._wait_state(lambda s: True, self.reconnect_timeout, back)
        if heard is None or heard.state is None:
            raise Failed(
                f"no state within {self.reconnect_timeout:g} s after the kit came back; a robot "
                "reconnects by itself (a Zenoh client does) and keeps publishing."
            )
        after = heard.state
        took = heard.at - back
        if working_on(after, rid):
            time.sleep(0.3)  # routes to the robot's queryable
            stop = self._ask(Cancel(request_id=rid))  # the request is over for this "IaaS"
            assert stop.ack is not None
            if not stop.ack.ok:
                raise Failed(f"after reconnecting, the robot refused the cancel of {rid}.")
            self._must_stop(rid, self._now())
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
        with self._changed:
            heard = list(self._heard)
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
                f"{refused[0].problem}",
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
        late = [s for s in self._sent if s.latency is None or s.latency > self.ack_timeout]
        if late:
            self._results["late-ack"] = Result("late-ack", False, self._late(late[0]))
        elif result is not None and result.passed:
            result.sentence += (
                f"; all {len(self._sent)} acks in time, the slowest in {self._slowest():.2f} s."
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
                "a robot publishes at least once a second (the IaaS counts it offline after 5 s).",
            )
        for before, after in itertools.pairwise(valid):
            assert before.state is not None and after.state is not None
            if after.state.seq <= before.state.seq:
                return Result(
                    "state-rate",
                    False,
                    f"seq went from {before.state.seq} to {after.state.seq} "
                    f"({after.at:.1f} s into the check); it increases with every state.",
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
                "by 100); if the robot is truly this low, charge it and check again.",
            )
        return Result("battery-percent", True, f"{min(batteries):g} to {top:g} %.")


# -- small pure helpers ---------------------------------------------------------------


def working_on(state: State, rid: str) -> bool:
    task = state.task
    return task is not None and task.request_id == rid and task.phase in WORKING


def idle(state: State) -> bool:
    return state.status == "idle" and (state.task is None or state.task.phase not in WORKING)


def finished_phase(state: State, rid: str) -> str | None:
    for task in (state.task, state.last_task):
        if task is not None and task.request_id == rid and task.phase in FINISHED_PHASES:
            return task.phase
    return None


def ended(state: State, rid: str) -> bool:
    return finished_phase(state, rid) is not None


def describe(state: State) -> str:
    task = state.task
    doing = f"{task.request_id} {task.phase}" if task is not None else "no task"
    return f"status {state.status}, {doing}"


def _xy(position: list[float]) -> str:
    return f"({position[0]:g}, {position[1]:g})"


def _location(state: State, metres: float) -> list[float]:
    """A point ``metres`` from the robot along x, inside the accepted coordinates."""
    x, y = state.position
    metres = min(metres, 1000.0)
    if x + metres > MAX_COORDINATE:
        return [x - metres, y]
    return [x + metres, y]

