"""Refused states are answered, not dropped in silence: the robot's error key and the log.

A state that does not validate (a missing field, a battery of 150, a state
published on another robot's key) is dropped, and the robot is told why on
``robocloud/<cloud>/robots/<id>/error`` with a ``StateError``: one sentence
naming the first field at fault. The IaaS's log says the same, with the field.

Both are bounded, whatever clients publish: at most one answer a second per
robot and ``MAX_ANSWERS_PER_S`` in all; a log line per robot when its fault
changes and at most once a minute while it repeats.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import pydantic
import zenoh

from robocloud.errors import InvalidInput, describe_validation_errors
from robocloud.fleet import keys
from robocloud.fleet.messages import MAX_BATCH_STATES, State, StateError

logger = logging.getLogger("robocloud.fleet.link")

# Seconds a state's sent_at may be from the IaaS's clock. A state from far in
# the future would otherwise pass for newer than every real one and hide the
# robot (docs/protocol.md); one from far in the past is a replay.
MAX_CLOCK_SKEW = 300.0
MAX_STATE_BYTES = 64 * 1024  # a state of a robot with 100 capabilities is about 8 KiB
__all__ = ["MAX_BATCH_STATES", "StateErrors"]
MAX_BATCH_BYTES = 16 * 1024 * 1024  # one gateway batch
ANSWER_EVERY = 1.0  # seconds between two answers to one robot
MAX_ANSWERS_PER_S = 200  # answers to all robots together
LOG_EVERY = 60.0  # seconds between two log lines for one robot's repeated fault
MAX_TRACKED = 10_000  # robots whose last answer and log line are remembered


def clock_refusal(state: State, now: float, bound: float = MAX_CLOCK_SKEW) -> str | None:
    """Why ``state`` is refused for its ``sent_at`` (``now``: the IaaS's unix time), or None."""
    apart = state.sent_at - now
    if abs(apart) <= bound:
        return None
    return (
        f"sent_at: the state was sent at {state.sent_at:.3f}, {abs(apart):.0f} s "
        f"{'ahead of' if apart > 0 else 'behind'} this IaaS's clock; at most {bound:g} s "
        "apart are accepted (set the robot's clock)."
    )


def _chunk(value: str) -> bool:
    try:
        keys.check_chunk(value, "robot")
    except InvalidInput:
        return False
    return True


class StateErrors:
    """Tells robots (and the log) why their states were refused, at a bounded rate."""

    def __init__(
        self,
        session: zenoh.Session,
        cloud: str,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
    ) -> None:
        self._session = session
        self._cloud = cloud
        self._clock = clock
        self._wall = wall
        self._lock = threading.Lock()
        self._answered: dict[str, float] = {}  # robot -> when it was last answered
        self._logged: dict[str, tuple[str, float]] = {}  # key -> (sentence, when logged)
        self._window = (0.0, 0)  # (second it counts, answers sent in it)
        self.answers = 0  # answers sent so far (for tests and the log)
        # robot -> why its last state was refused, until one of its states is
        # accepted (GET /v1/robots shows it); at most MAX_TRACKED robots.
        self._refused: dict[str, str] = {}
        self._counts: dict[str, int] = {}  # field -> states refused for it

    def counts(self) -> dict[str, int]:
        """States refused so far, by the field that was wrong (``state``: the whole)."""
        with self._lock:
            return dict(self._counts)

    def refused(self) -> dict[str, str]:
        """Why each robot's last state was refused, for robots with no state accepted since."""
        with self._lock:
            return dict(self._refused)

    def accepted(self, robots: list[str]) -> None:
        """States of these robots were accepted: their refusals are over."""
        if self._refused:  # mostly empty: nothing to lock for
            with self._lock:
                for robot in robots:
                    self._refused.pop(robot, None)

    def too_large(self, key: str, size: int) -> None:
        self.refuse(
            key,
            "state",
            f"the state is {size} bytes; at most {MAX_STATE_BYTES} are accepted.",
        )

    def invalid(self, key: str, error: pydantic.ValidationError) -> None:
        described = describe_validation_errors(error.errors())
        self.refuse(key, described.field or "state", described.message)

    def mismatch(self, key: str, state: State) -> None:
        robot = keys.robot_of(key)
        if state.cloud != self._cloud:
            self.refuse(
                key,
                "cloud",
                f"cloud: the state names cloud {state.cloud} but came on a key of {self._cloud}.",
            )
        else:
            self.refuse(
                key, "id", f"id: the state names robot {state.id} but came on the key of {robot}."
            )

    def refuse(self, key: str, field: str, sentence: str, robot: str | None = None) -> None:
        """Log and answer one refused state that came on ``key``.

        The answer goes to the robot of the key, or to ``robot`` for a state
        of a gateway's batch (the robot its ``id`` names, when it can stand
        in a key); none when neither is known.
        """
        if robot is None:
            robot = keys.robot_of(key)
        elif not _chunk(robot):
            robot = None
        now = self._clock()
        with self._lock:
            if field in self._counts or len(self._counts) < 64:  # fields are few; bounded
                self._counts[field] = self._counts.get(field, 0) + 1
            log = self._due_log(key, sentence, now)
            answer = robot is not None and self._due_answer(robot, now)
            if robot and (robot in self._refused or len(self._refused) < MAX_TRACKED):
                self._refused[robot] = sentence
        if log:
            logger.warning("refused a state on %s (field %s): %s", key, field, sentence)
        if answer and robot is not None:
            message = StateError(robot=robot, field=field, error=sentence, sent_at=self._wall())
            try:
                self._session.put(
                    keys.error_key(self._cloud, robot),
                    message.model_dump_json(),
                    encoding=zenoh.Encoding.APPLICATION_JSON,
                )
                self.answers += 1
            except Exception as error:  # a closing session; the log has said it already
                logger.debug("could not answer %s: %s", robot, error)

    def in_batch(self, key: str, robot: str | None, field: str, sentence: str) -> None:
        """A state of the batch on ``key`` was refused: its robot hears why, when it is named."""
        where = f"{key} (robot {robot})" if robot is not None else key
        self.refuse(where, field, sentence, robot=robot if robot is not None else "")

    def _due_log(self, key: str, sentence: str, now: float) -> bool:
        said = self._logged.get(key)
        if said is not None and said[0] == sentence and now - said[1] < LOG_EVERY:
            return False
        if len(self._logged) >= MAX_TRACKED:
            self._logged.clear()
        self._logged[key] = (sentence, now)
        return True

    def _due_answer(self, robot: str, now: float) -> bool:
        if now - self._answered.get(robot, -ANSWER_EVERY) < ANSWER_EVERY:
            return False
        second, count = self._window
        if int(now) != second:
            second, count = int(now), 0
        if count >= MAX_ANSWERS_PER_S:
            return False
        self._window = (second, count + 1)
        if len(self._answered) >= MAX_TRACKED:
            self._answered.clear()
        self._answered[robot] = now
        return True
