"""What the kit holds a robot to: the rules of docs/protocol.md, as data and pure checks.

No I/O here (``transport.py`` talks to the robot, ``kit.py`` runs the
scenarios). Each rule names the section of docs/protocol.md it comes from, so
a failure says what the robot did and where the page says otherwise.

Every message the robot sends is read twice: against the JSON Schemas of
docs/protocol/ (``robocloud.fleet.schemas``, the contract: a battery of
``"80"`` is a string, not a number, and is refused), then into the models of
``robocloud.fleet.messages``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from dataclasses import dataclass
from functools import cache
from typing import Any

import jsonschema_rs
import pydantic

from robocloud.domain.robot import MAX_COORDINATE
from robocloud.errors import describe_validation_errors
from robocloud.fleet.messages import FINISHED_PHASES, Ack, State
from robocloud.fleet.schemas import file_name, protocol_schema


@dataclass(frozen=True)
class Rule:
    what: str  # one line: what is checked
    section: str  # the section of docs/protocol.md that says so


STATE = "State"
COMMANDS = "Commands and acks"
TIMING = "Timing"
RECONNECT = "Reconciliation and reconnection"
UNITS = "Units and frame"
MISSIONS = "Missions (protocol 1.2)"

RULES: dict[str, Rule] = {
    "join": Rule("the robot publishes its state on its key", "Keys"),
    "state-schema": Rule(
        "every state is valid against state.schema.json and names its robot", STATE
    ),
    "state-rate": Rule("a state at least once a second, seq increasing", STATE),
    "battery-percent": Rule("battery is a percent from 0 to 100, not a fraction", UNITS),
    "idle": Rule("the robot starts idle, with a capability to use", STATE),
    "assign": Rule("an assign is acknowledged ok in time and reported at once", COMMANDS),
    "repeat-assign": Rule("the same assign again is acknowledged ok", COMMANDS),
    "refuse-busy": Rule(
        "an assign for another request while busy is refused with a sentence", COMMANDS
    ),
    "progress": Rule(
        "phases move forward, progress grows from 0 to 1, the robot nears the location", STATE
    ),
    "done": Rule(
        "the task ends done in its expected time, the robot idle at the location", COMMANDS
    ),
    "overrun": Rule("a robot past its expected finish is stopped, and obeys", COMMANDS),
    "last-task": Rule("the finished task stays in last_task until the next one", STATE),
    "cancel-after-finish": Rule(
        "a cancel of a finished task is ok and changes nothing, last_task kept", COMMANDS
    ),
    "cancel": Rule("a cancel is acknowledged and the robot stops, idle, within a second", COMMANDS),
    "malformed-command": Rule(
        "a command that is not valid gets an ack, ok false with a sentence, and no action", COMMANDS
    ),
    "late-ack": Rule(
        "every ack within the deadline; a cancel right after an assign is obeyed", COMMANDS
    ),
    "reconnect": Rule(
        "after an outage the robot reports its task again and obeys the cancel", RECONNECT
    ),
    "hold": Rule(
        "protocol 1.2: an assign with hold is driven to and waited at, worked on its start "
        "only; a start for another request is refused",
        MISSIONS,
    ),
}
WORKING = frozenset({"travel", "waiting", "work"})
PHASE_ORDER = {"travel": 0, "waiting": 1, "work": 2, "done": 3, "failed": 3}
RATE_SLACK = 0.3  # seconds of jitter tolerated over "at least once a second"
LATE_GRACE = 3.0  # seconds the kit still listens for an ack past the deadline
RECONNECT_TRAVEL = 30.0  # seconds of travel of the task that spans the outage
AT_LOCATION = 1.0  # metres: how near the location "done" must be
# The IaaS's watchdog (docs/protocol.md, "Timing"): a robot is past its expected
# finish when it has taken longer than expected plus the larger of OVERRUN_SHARE
# of it and ``Timing.overrun_min``.
OVERRUN_SHARE = 0.5


@dataclass(frozen=True)
class Timing:
    """How long the kit waits for the robot and watches it, in seconds.

    The defaults are those of docs/protocol.md and the IaaS, for a real robot;
    each is an option of ``robocloud robot-check`` (``--report-within`` for
    ``report_within``, ...). A robot that is quick to observe (a simulator at a
    speed-up, a robot on loopback that publishes twice a second) can be checked
    with shorter ones: the rules stay the same, only the windows shrink. A
    deadline (``report_within``, ``clean_within``, the timeouts) ends as soon as
    the robot meets it; a window (``watch``, ``linger``, ``outage``) is watched
    to its end, so it should span a few of the robot's states.
    """

    ack_timeout: float = 2.0  # the IaaS's --ack-timeout: a later ack counts as a refusal
    join_timeout: float = 15.0  # for the robot's first state
    task_timeout: float = 120.0  # the longest the kit waits for a task to end
    outage: float = 2.0  # how long the kit stays away in the reconnect rule
    reconnect_timeout: float = 20.0  # for the robot's first state after the outage
    overrun_min: float = 30.0  # the IaaS's --overrun-min: the watchdog's least tolerance
    travel: float = 2.0  # seconds of travel (at the robot's speed) of the kit's tasks
    report_within: float = 1.0  # from a command to the state that shows its change
    watch: float = 1.0  # after a cancel or a refusal: the robot must not take the task up
    linger: float = 4.0  # last_task watched after a task ended (past the 3 s a task stays)
    clean_within: float = 3.0  # for a robot told to cancel to be idle before a scenario


class Failed(Exception):
    """A rule failed; the message is its sentence."""


@dataclass
class Result:
    rule: str
    passed: bool
    sentence: str


def malformed(rid: str, capability: str) -> list[tuple[str, bytes]]:
    """Commands that are not valid, each with what is wrong with it (malformed-command)."""
    unknown = {"type": "teleport", "request_id": rid}
    lost = {"type": "assign", "request_id": rid, "capabilities": [capability]}
    return [
        ("a payload that is not JSON", b"{not json"),
        ("a command of an unknown type", json.dumps(unknown).encode()),
        ("an assign without location", json.dumps(lost).encode()),
    ]


def where(rule: str) -> str:
    return f'docs/protocol.md, "{RULES[rule].section}"'


def cite(sentence: str, rule: str) -> str:
    """``sentence`` with the section of docs/protocol.md that sets ``rule``."""
    return f"{sentence.rstrip('.')} ({where(rule)})."


def tolerance(expected: float, at_least: float = Timing.overrun_min) -> float:
    """The watchdog's allowance past an expected time: the larger of 50 % and ``at_least``."""
    return max(OVERRUN_SHARE * expected, at_least)


# -- reading what the robot sends ---------------------------------------------------------


@dataclass(frozen=True)
class Reading:
    """A message of the robot: the model when it is valid, else the field and the sentence."""

    state: State | None
    field: str | None = None
    problem: str | None = None


@cache
def _validator(name: str) -> Any:
    return jsonschema_rs.validator_for(protocol_schema(name))


def schema_problem(name: str, document: Any) -> tuple[str, str] | None:
    """``(field, sentence)`` of the first thing ``name``'s schema refuses in ``document``."""
    errors = list(_validator(name).iter_errors(document))
    if not errors:
        return None
    error = _deepest(errors)
    path = [str(p) for p in error.instance_path]
    field = ".".join(path) or name
    return field, f"{field}: {error.message} ({file_name(name)})."


def _deepest(errors: Iterable[Any]) -> Any:
    """The error that says most: inside anyOf (a field that may be null) the branch's own."""
    best = None
    for error in errors:
        inner = getattr(error.kind, "context", None)
        if inner:
            candidate = _deepest(e for branch in inner for e in branch)
            if len(candidate.instance_path) >= len(error.instance_path):
                error = candidate
        if best is None or len(error.instance_path) > len(best.instance_path):
            best = error
    return best


def read_state(payload: bytes, cloud: str, robot: str) -> Reading:
    """A state as the protocol reads it: JSON, the schema, the model, the robot of its key."""
    try:
        document = json.loads(payload)
    except ValueError:
        return Reading(None, "state", "the payload is not JSON.")
    try:
        state = State.model_validate(document)
    except pydantic.ValidationError as error:
        described = describe_validation_errors(error.errors())
        return Reading(None, described.field or "state", described.message)
    # The models read leniently ("80" is taken for 80); the schemas, the contract, do not.
    problem = schema_problem("state", document)
    if problem is not None:
        return Reading(None, *problem)
    if state.id != robot or state.cloud != cloud:
        return Reading(None, "id", f"it names robot {state.cloud}/{state.id}, not {cloud}/{robot}.")
    return Reading(state)


def read_ack(payload: bytes, what: str) -> tuple[Ack | None, str | None]:
    """The robot's reply to ``what`` (a phrase naming the command) as an Ack, or why not."""
    try:
        document = json.loads(payload)
    except ValueError:
        return None, f"the reply to {what} is not JSON."
    problem = schema_problem("ack", document)
    if problem is not None:
        return None, f"the reply to {what} is not an Ack: {problem[1]}"
    try:
        return Ack.model_validate(document), None
    except pydantic.ValidationError as error:
        described = describe_validation_errors(error.errors(), "ack").message
        return None, f"the reply to {what} is not an Ack: {described}"


# -- small pure checks --------------------------------------------------------------------


def working_on(state: State, rid: str) -> bool:
    task = state.task
    return task is not None and task.request_id == rid and task.phase in WORKING


def working(state: State) -> str | None:
    """The request the robot works on (travel or work), if any."""
    task = state.task
    return task.request_id if task is not None and task.phase in WORKING else None


def idle(state: State) -> bool:
    return state.status == "idle" and (state.task is None or state.task.phase not in WORKING)


def finished_phase(state: State, rid: str) -> str | None:
    for task in (state.task, state.last_task):
        if task is not None and task.request_id == rid and task.phase in FINISHED_PHASES:
            return task.phase
    return None


def phase_of(state: State, rid: str) -> str | None:
    """The phase the robot reports for ``rid``: its task's, or its last task's once over."""
    for task in (state.task, state.last_task):
        if task is not None and task.request_id == rid:
            return task.phase
    return None


def ended(state: State, rid: str) -> bool:
    return finished_phase(state, rid) is not None


def describe(state: State | None) -> str:
    if state is None:
        return "nothing valid"
    task = state.task
    doing = f"{task.request_id} {task.phase}" if task is not None else "no task"
    return f"status {state.status}, {doing}"


def xy(position: list[float]) -> str:
    return f"({position[0]:g}, {position[1]:g})"


def location(state: State, metres: float) -> list[float]:
    """A point ``metres`` from the robot along x, inside the accepted coordinates."""
    x, y = state.position
    metres = min(metres, 1000.0)
    if x + metres > MAX_COORDINATE:
        return [x - metres, y]
    return [x + metres, y]


def distance(a: list[float], b: list[float]) -> float:
    return math.dist(a, b)
