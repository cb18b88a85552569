"""Reading robot states fast: msgspec decodes, pydantic only explains a refusal.

A cloud of 50,000 robots at 1 Hz sends 50,000 states a second; pydantic's
validation of each, and the building of its models, cost more than a core.
Here a state is decoded by msgspec into ``WireState`` (the same constraints
as ``robocloud.fleet.messages.State``, less the name pattern, which a light
check replaces) and turned into a ``State`` without validating it again.

Whatever the fast path refuses goes to pydantic, which either accepts it
(a lax form the fast path does not take, e.g. a number in a string) or
refuses it with the sentence naming the field that robots have always had
(``battery: input should be less than or equal to 100.``). So the fast path
only ever accepts what pydantic accepts, and errors read the same.

``WireState`` is also what a gateway encodes (``robocloud.sim.fleet``):
msgspec writes a batch of them in a few microseconds per state.
"""

from __future__ import annotations

import math
from collections.abc import Container
from dataclasses import dataclass
from typing import Annotated, Any, Literal, TypeVar

import msgspec
import pydantic
from msgspec import Meta

from robocloud.domain import Capability
from robocloud.domain.robot import MAX_AMOUNT, MAX_COORDINATE, MAX_SPEED, MIN_SPEED
from robocloud.errors import describe_validation_errors
from robocloud.fleet.messages import MAX_SESSION_LENGTH, SESSION_PATTERN, State, TaskProgress

# Without the name pattern (a regex per string costs more than the rest of
# the state): ``_names_ok`` checks names instead, remembering those seen.
_Name = Annotated[str, Meta(min_length=1, max_length=128)]
_Coordinate = Annotated[float, Meta(ge=-MAX_COORDINATE, le=MAX_COORDINATE)]
_Amount = Annotated[float, Meta(ge=0.0, le=MAX_AMOUNT)]


class WireCapability(msgspec.Struct, frozen=True, forbid_unknown_fields=True, gc=False):
    kind: Literal["sensing", "actuating"]
    time: _Amount
    cost: _Amount


class WireTask(msgspec.Struct, frozen=True, gc=False):
    request_id: _Name
    phase: Literal["travel", "waiting", "work", "done", "failed"]
    progress: Annotated[float, Meta(ge=0.0, le=1.0)]
    capabilities: list[_Name]
    reason: Annotated[str, Meta(max_length=300)] | None = None  # protocol 1.1


class WireState(msgspec.Struct, gc=False):
    """A robot's state as msgspec reads and writes it (fields as in ``State``)."""

    id: _Name
    cloud: _Name
    kind: _Name
    position: Annotated[list[_Coordinate], Meta(min_length=2, max_length=2)]
    speed: Annotated[float, Meta(ge=MIN_SPEED, le=MAX_SPEED)]
    battery: Annotated[float, Meta(ge=0.0, le=100.0)]
    status: Literal["idle", "reserved", "busy", "charging", "offline"]
    travel_cost_per_m: _Amount
    # Their JSON as it came: a robot's capabilities rarely change, so they
    # are checked and made into models once per distinct text.
    capabilities: msgspec.Raw
    seq: Annotated[int, Meta(ge=0)]
    sent_at: float
    task: WireTask | None = None
    last_task: WireTask | None = None
    protocol: Annotated[str, Meta(max_length=16, pattern=r"^[0-9]+\.[0-9]+$")] | None = None  # 1.2
    session: (  # 1.2
        Annotated[str, Meta(min_length=1, max_length=MAX_SESSION_LENGTH, pattern=SESSION_PATTERN)]
        | None
    ) = None


class _Id(msgspec.Struct):
    """Only the robot id of a state, to tell the right robot why its state was refused."""

    id: str


_DECODER = msgspec.json.Decoder(WireState)
_CAPABILITIES_DECODER = msgspec.json.Decoder(dict[_Name, WireCapability])
_ID_DECODER = msgspec.json.Decoder(_Id)
_BATCH_DECODER = msgspec.json.Decoder(list[msgspec.Raw])
_STATES_DECODER = msgspec.json.Decoder(list[WireState])
_ENCODER = msgspec.json.Encoder()
_MAX_REMEMBERED = 200_000  # names and capability sets kept, whatever robots send

_STATE_FIELDS = frozenset(State.model_fields)
_TASK_FIELDS = frozenset(TaskProgress.model_fields)
_new = object.__new__
_set = object.__setattr__

M = TypeVar("M", State, TaskProgress)


def _built(model: type[M], values: dict[str, Any], fields: frozenset[str]) -> M:
    """A model holding ``values`` (every field), made as pydantic's own constructor leaves
    it but without validating again: what msgspec decoded is already checked."""
    built = _new(model)
    _set(built, "__dict__", values)
    _set(built, "__pydantic_fields_set__", fields)
    _set(built, "__pydantic_extra__", None)
    _set(built, "__pydantic_private__", None)
    return built


def _names_ok(names: set[str], *values: str) -> bool:
    """Whether every value matches ``NAME_PATTERN`` (no control character): a set of those seen."""
    for value in values:
        if value not in names:
            # Stricter than the pattern (it also refuses e.g. non-ASCII
            # spaces): a name it refuses goes to pydantic, which decides.
            if not value.isprintable():
                return False
            if len(names) >= _MAX_REMEMBERED:
                names.clear()
            names.add(value)
    return True


@dataclass
class Refusal:
    """A state not accepted: the robot it names (when readable), the field, the sentence."""

    robot: str | None
    field: str
    sentence: str


class StateReader:
    """Reads states into ``State`` models; remembers names and capability sets it has seen.

    One per link: not for several threads at once (Zenoh calls a
    subscriber's callback on one thread at a time).
    """

    def __init__(self) -> None:
        self._names: set[str] = set()
        # Each session's text once: the robots of a simulator or gateway share theirs, and a
        # link keeps 100,000 states (memory per robot, benchmarks/memory.py).
        self._sessions: dict[str, str] = {}
        # Capability sets are few (robots of a kind share them): each is made
        # into pydantic Capabilities once, and states share the dict (states
        # are frozen; ``to_robot`` copies it).
        self._capabilities: dict[bytes, dict[str, Capability]] = {}

    def read(self, payload: bytes) -> State | Refusal:
        """One state from its JSON: a ``State``, or why it is refused."""
        try:
            wire = _DECODER.decode(payload)
        except msgspec.DecodeError:
            return self._slow(payload)
        state = self._model(wire)
        return state if state is not None else self._slow(payload)

    def read_batch(
        self,
        payload: bytes,
        max_state_bytes: int = 64 * 1024,
        only: Container[str] | None = None,
    ) -> tuple[list[State], list[Refusal]]:
        """The states of a batch (a JSON array of states), and the refusals of bad ones.

        A bad state costs only itself: the others of the batch are read. A
        payload that is not an array at all is one refusal naming no robot.
        With ``only``, the states of other robots are skipped unread (by their
        ``id`` alone), neither kept nor refused.
        """
        if only is None:
            fast = self._fast_batch(payload, max_state_bytes)
            if fast is not None:
                return fast, []
        try:
            items = _BATCH_DECODER.decode(payload)
        except msgspec.DecodeError as error:
            sentence = f"the batch is not a JSON array of states ({error})."
            return [], [Refusal(None, "states", sentence)]
        states: list[State] = []
        refusals: list[Refusal] = []
        for item in items:
            raw = bytes(item)
            if only is not None and robot_named(raw) not in only:
                continue
            if len(raw) > max_state_bytes:
                sentence = f"the state is {len(raw)} bytes; at most {max_state_bytes} are accepted."
                refusals.append(Refusal(robot_named(raw), "state", sentence))
                continue
            read = self.read(raw)
            if isinstance(read, Refusal):
                refusals.append(read)
            else:
                states.append(read)
        return states, refusals

    def _fast_batch(self, payload: bytes, max_state_bytes: int) -> list[State] | None:
        """Every state of a batch in one msgspec call; None when any needs a closer look.

        The common case: a gateway's batch of valid states. A batch with one
        bad state (or one the light checks send to pydantic, or one that may
        be over ``max_state_bytes``) is read again state by state, so each
        gets its own verdict.
        """
        try:
            wires = _STATES_DECODER.decode(payload)
        except msgspec.DecodeError:
            return None
        # Other fields are short (names of at most 128 characters): only these
        # can make a state large.
        large = max_state_bytes // 2
        many = max_state_bytes // 1024
        states = []
        for wire in wires:
            if (
                len(wire.capabilities) > large
                or (wire.task is not None and len(wire.task.capabilities) > many)
                or (wire.last_task is not None and len(wire.last_task.capabilities) > many)
            ):
                return None
            state = self._model(wire)
            if state is None:
                return None
            states.append(state)
        return states

    def _slow(self, payload: bytes) -> State | Refusal:
        try:
            # Strict, as msgspec and the schemas are: a number sent as a string
            # ("80") is refused, not taken (docs/protocol.md: the schemas win).
            return State.model_validate_json(payload, strict=True)
        except pydantic.ValidationError as error:
            described = describe_validation_errors(error.errors())
            return Refusal(robot_named(payload), described.field or "state", described.message)

    def _model(self, wire: WireState) -> State | None:
        """The ``State`` of a decoded state, None when a light check fails (pydantic decides)."""
        names = self._names
        if (
            wire.id not in names or wire.cloud not in names or wire.kind not in names
        ) and not _names_ok(names, wire.id, wire.cloud, wire.kind):
            return None
        if not math.isfinite(wire.sent_at):
            return None
        capabilities = self._capabilities.get(bytes(wire.capabilities))
        if capabilities is None:
            capabilities = self._capability_set(bytes(wire.capabilities))
            if capabilities is None:
                return None
        task = last = None
        if wire.task is not None:
            task = self._task(wire.task)
            if task is None:
                return None
        if wire.last_task is not None:
            last = task if wire.last_task == wire.task else self._task(wire.last_task)
            if last is None:
                return None
        return _built(
            State,
            {
                "id": wire.id,
                "cloud": wire.cloud,
                "kind": wire.kind,
                "position": wire.position,
                "speed": wire.speed,
                "battery": wire.battery,
                "status": wire.status,
                "travel_cost_per_m": wire.travel_cost_per_m,
                "capabilities": capabilities,
                "task": task,
                "last_task": last,
                "seq": wire.seq,
                "sent_at": wire.sent_at,
                "protocol": wire.protocol,
                "session": self._session(wire.session),
            },
            _STATE_FIELDS,
        )

    def _session(self, session: str | None) -> str | None:
        if session is None:
            return None
        kept = self._sessions.get(session)
        if kept is None:
            if len(self._sessions) >= _MAX_REMEMBERED:
                self._sessions.clear()
            kept = self._sessions[session] = session
        return kept

    def _capability_set(self, raw: bytes) -> dict[str, Capability] | None:
        """The capabilities of ``raw`` (their JSON), checked once and remembered by their bytes."""
        try:
            decoded = _CAPABILITIES_DECODER.decode(raw)
        except msgspec.DecodeError:
            return None
        if not _names_ok(self._names, *decoded):
            return None
        if len(self._capabilities) >= _MAX_REMEMBERED:
            self._capabilities.clear()
        capabilities = self._capabilities[raw] = {
            name: Capability.model_construct(kind=c.kind, time=c.time, cost=c.cost)
            for name, c in decoded.items()
        }
        return capabilities

    def _task(self, wire: WireTask) -> TaskProgress | None:
        if not _names_ok(self._names, wire.request_id, *wire.capabilities):
            return None
        return _built(
            TaskProgress,
            {
                "request_id": wire.request_id,
                "phase": wire.phase,
                "progress": wire.progress,
                "capabilities": wire.capabilities,
                "reason": wire.reason,
            },
            _TASK_FIELDS,
        )


def robot_named(payload: bytes) -> str | None:
    """The ``id`` a refused state names, if it can be read at all."""
    try:
        return _ID_DECODER.decode(payload).id
    except msgspec.DecodeError:
        return None


def encode_batch(states: list[WireState | dict[str, Any]]) -> bytes:
    """A batch's payload: the JSON array of ``states``."""
    return _ENCODER.encode(states)


def wire_task(task: TaskProgress | None) -> WireTask | None:
    if task is None:
        return None
    return WireTask(
        task.request_id, task.phase, task.progress, list(task.capabilities), task.reason
    )
