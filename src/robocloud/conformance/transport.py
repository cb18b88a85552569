"""The kit's side of Zenoh: what an IaaS says to one robot and hears from it.

By default a Zenoh router listening on the endpoint the robot connects to, as
``robocloud iaas --zenoh`` is; with ``client=True`` a client of a router
already there. ``close`` and ``open`` again are an IaaS that restarts (the
``reconnect`` scenario). It keeps every state heard, read by
``rules.read_state`` (a refused one is answered on the robot's error key, as
the IaaS does), and sends commands whose acks come in the background.

No rule is judged here: ``kit.py`` does that with ``rules.py``.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import zenoh

from robocloud.conformance.rules import read_ack, read_state
from robocloud.fleet import keys
from robocloud.fleet.messages import Ack, Assign, Cancel, Start, State
from robocloud.fleet.state_errors import StateErrors
from robocloud.fleet.zenoh_session import open_client, open_router


@dataclass
class Heard:
    at: float  # seconds since the check began
    state: State | None
    problem: str | None = None  # why the message was refused


@dataclass
class Sent:
    """One command and its ack."""

    what: str  # "the assign of check-1-2", "a payload that is not JSON"
    request_id: str | None
    at: float  # monotonic, when sent
    answered: threading.Event = field(default_factory=threading.Event)
    ack: Ack | None = None
    problem: str | None = None  # the reply was not an Ack of this robot
    latency: float | None = None
    replies: int = 0


def what_of(command: Assign | Cancel | Start) -> str:
    return f"the {command.type} of {command.request_id}"


class Transport:
    """Zenoh to robot ``robot`` of ``cloud`` through ``endpoint``."""

    def __init__(
        self, endpoint: str, cloud: str, robot: str, *, client: bool, reply_timeout: float
    ) -> None:
        self.endpoint, self.cloud, self.robot = endpoint, cloud, robot
        self.client = client
        self.reply_timeout = reply_timeout  # how long a query listens for its reply
        self.start = time.monotonic()
        self.heard: list[Heard] = []
        self.sent: list[Sent] = []
        self.changed = threading.Condition()
        self._session: zenoh.Session | None = None
        self._subscriber: zenoh.Subscriber[None] | None = None
        self._errors: StateErrors | None = None

    def now(self) -> float:
        """Seconds since the check began."""
        return time.monotonic() - self.start

    # -- the session ------------------------------------------------------------------

    def open(self) -> None:
        if self.client:
            session = open_client([self.endpoint], timeout=5.0)
        else:
            session = open_router([self.endpoint])
        self._session = session
        self._errors = StateErrors(session, self.cloud)
        self._subscriber = session.declare_subscriber(
            keys.state_key(self.cloud, self.robot), self._on_state
        )

    def close(self) -> None:
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
        at = self.now()
        key = str(sample.key_expr)
        reading = read_state(sample.payload.to_bytes(), self.cloud, self.robot)
        if reading.state is None and self._errors is not None:
            self._errors.refuse(key, reading.field or "state", reading.problem or "refused.")
        with self.changed:
            self.heard.append(Heard(at, reading.state, reading.problem))
            self.changed.notify_all()

    # -- commands ---------------------------------------------------------------------

    def command(self, command: Assign | Cancel | Start) -> Sent:
        """Send ``command``; the Sent is answered in the background (``answered``)."""
        return self.send(command.model_dump_json().encode(), what_of(command), command.request_id)

    def send(self, payload: bytes, what: str, request_id: str | None) -> Sent:
        """Send ``payload`` as a command (``what`` names it in sentences)."""
        sent = Sent(what, request_id, time.monotonic())
        self.sent.append(sent)

        def on_reply(reply: zenoh.Reply) -> None:
            sample = reply.ok
            if sample is None:
                error = reply.err
                detail = error.payload.to_string() if error is not None else ""
                if detail == "Timeout" or sent.answered.is_set():
                    return  # Zenoh's own word that nobody answered in time
                sent.problem = f"the robot answered {what} with an error: {detail}"
                sent.answered.set()
                return
            sent.replies += 1
            if sent.answered.is_set():
                return
            sent.latency = time.monotonic() - sent.at
            ack, problem = read_ack(sample.payload.to_bytes(), what)
            if ack is not None:
                if ack.robot != self.robot:
                    problem = f"the ack of {what} names robot {ack.robot}."
                elif ack.request_id not in (None, request_id):
                    problem = f"the ack of {what} names request {ack.request_id}."
            sent.ack, sent.problem = ack, problem
            sent.answered.set()

        if self._session is None:
            raise RuntimeError("the kit's Zenoh session is closed")
        self._session.get(
            keys.cmd_key(self.cloud, self.robot),
            on_reply,
            payload=payload,
            encoding=zenoh.Encoding.APPLICATION_JSON,
            target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=self.reply_timeout,
        )
        return sent

    def wait_routed(self, timeout: float) -> bool:
        """Whether the robot's command queryable reached the kit's session within ``timeout``.

        Its first state may come before its queryable is known here; a command sent
        then would find nobody to answer it.
        """
        if self._session is None:
            return False
        querier = self._session.declare_querier(keys.cmd_key(self.cloud, self.robot))
        try:
            deadline = time.monotonic() + timeout
            # A MatchingStatus, not the bool its stub says (eclipse-zenoh 1.x).
            while not querier.matching_status.matching:  # type: ignore[attr-defined]
                if time.monotonic() >= deadline:
                    return False
                time.sleep(0.01)
            return True
        finally:
            with contextlib.suppress(zenoh.ZError):
                querier.undeclare()  # type: ignore[no-untyped-call]

    # -- states -----------------------------------------------------------------------

    def wait_state(
        self, test: Callable[[State], bool], timeout: float, since: float
    ) -> Heard | None:
        """The first valid state heard after ``since`` (seconds into the run) that passes."""
        deadline = time.monotonic() + timeout
        with self.changed:
            while True:
                for heard in self.heard:
                    if heard.at >= since and heard.state is not None and test(heard.state):
                        return heard
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self.changed.wait(left)

    def wait_heard(self, timeout: float) -> list[Heard]:
        """Everything heard, once something is (or ``timeout`` passed)."""
        with self.changed:
            self.changed.wait_for(lambda: bool(self.heard), timeout)
            return list(self.heard)

    def states(self, since: float, until: float = math.inf) -> list[Heard]:
        with self.changed:
            return [h for h in self.heard if since <= h.at <= until and h.state is not None]

    def all_heard(self) -> list[Heard]:
        with self.changed:
            return list(self.heard)

    def latest(self) -> State | None:
        with self.changed:
            for heard in reversed(self.heard):
                if heard.state is not None:
                    return heard.state
        return None
