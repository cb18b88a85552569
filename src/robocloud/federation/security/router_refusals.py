"""What a cloud's router refused: Zenoh's access control decisions, as log lines and a metric.

The router (``policy.access_control``) drops a message its rules do not allow
before anything of robocloud sees it: a robot's certificate declaring a
cloud's presence, answering for a cloud, or putting another robot's state
reaches nobody. Zenoh 1.10 tells the application nothing of it; it only
writes each decision in its trace (target ``ACL_TARGET``, level trace) on
the process's standard output. ``watch`` turns that trace on, reads it back,
and for every refused message coming in (ingress) writes a robocloud log
line (``robocloud.federation.security.router_refusals``) and counts it
(``robocloud_router_refusals``, by the certificate's name and the message).

**How a decision is read.** Zenoh checks a message against each subject of
the policy that the session matches (here ``anyone``, and the one its
certificate names), one trace line each, and stops at the first that allows
it. So a refused message is as many "unauthorized" lines as the session has
subjects (``subjects_of``), an allowed one ends with "authorized". When a
key expression is first declared, Zenoh computes and caches the decisions
for every kind of message on it (lines after "caching permissions for"):
those are nobody's messages and are skipped; the decision for the
declaration itself follows them ("Using cached result: ..." or a line of its
own). The format is Zenoh 1.10's (``requirements.lock``);
tests/federation/test_router_refusals.py reads a real router's trace, so a
change of format fails there.

**Why the trace cannot be forged.** A key expression may hold a newline, so
an attacker can make Zenoh write a line of its choosing. Zenoh's own lines
start with an ANSI escape (the timestamp's dim colour) and Zenoh escapes the
ESC character in what it prints of a message; a line without that raw ESC at
its start is the rest of the line before it (a key with a newline), never a
decision. ``NO_COLOR`` is taken out of the environment while the trace is
turned on, so the escapes are there.

**The cost.** The trace has a line for every message the router checks,
allowed ones included (benchmarks/results/design-notes.md). It is on only for
a router with access control (``robocloud iaas`` with mutual TLS or logins).
It is process-wide: Zenoh has one trace per process, and standard output
(file descriptor 1) becomes a pipe read here; what is not the access
control's trace is copied to the real standard output, and Python's own
``sys.stdout`` writes there directly.
"""

from __future__ import annotations

import contextlib
import fcntl
import io
import logging
import os
import re
import select
import sys
import threading
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

logger = logging.getLogger(__name__)

ACL_TARGET = "zenoh::net::routing::interceptor::access_control"

# Zenoh's names of the message kinds in its trace, as the access control's
# configuration names them (policy.py). The cache's "Declare/Undeclare X" and a
# declaration's "Declare X" are one kind.
MESSAGE_NAMES = {
    "put": "put",
    "delete": "delete",
    "query": "query",
    "reply": "reply",
    "subscriber": "declare_subscriber",
    "queryable": "declare_queryable",
    "liveliness token": "liveliness_token",
    "liveliness query": "liveliness_query",
    "liveliness subscriber": "declare_liveliness_subscriber",
}
# The last kind of a block of cached decisions (Zenoh 1.10 caches them in this order:
# query, reply, put, delete, subscriber, queryable, token, liveliness query, this).
_LAST_CACHED = "declare_liveliness_subscriber"

# One line of Zenoh's trace, its colours taken out.
_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_LINE = re.compile(
    r"^\S+Z\s+(?P<level>[A-Z]+)\s+(?P<thread>.*?ThreadId\(\d+\))\s+(?P<target>[\w:]+): "
    r"(?P<body>.*)$",
    re.DOTALL,
)
_CACHING = re.compile(r"^ACL \((?P<flow>ingress|egress)\): caching permissions for `")
_DECISION = re.compile(
    r"^(?P<cached>Using cached result: )?(?P<zid>[0-9a-f]+)(?: on (?P<subject>.+?))? "
    r"is (?P<verdict>authorized|unauthorized) to (?P<action>.+?) \((?P<flow>ingress|egress)\) "
    r"on (?P<key>.*)$",
    re.DOTALL,
)
# A key as the cached decisions print it (Rust's Debug of an optional key expression).
_DEBUG_KEY = re.compile(r"^Some\(ke`(?P<key>.*)`\)$", re.DOTALL)
_NAMED = {
    "cert_common_names": re.compile(r"CertCommonName\(([^)]*)\)"),
    "usernames": re.compile(r"Username\(([^)]*)\)"),
}
# The raw pieces of an allowed decision's line, for ``TraceReader._allowed``.
_ALLOWED = " is authorized to "
_REFUSED = " is unauthorized to "
_ACL_MARK = f"{ACL_TARGET}\x1b[0m"
_AFTER_LEVEL = "TRACE\x1b[0m "
_BEFORE_TARGET = " \x1b[2mzenoh::"
# Where a line of Zenoh's own starts (the dim timestamp): nothing Zenoh prints of a
# message can hold a raw ESC, it escapes it.
_OWN_LINE = b"\x1b[2m"
# Of the refusals of one (party, message), the first ones are logged one by one, then every
# 1,000th: an attacker's flood is counted whole but leaves a bounded log.
LOG_FIRST = 20


def message_name(action: str) -> str:
    """The access control's name of a kind of message, from Zenoh's words in its trace."""
    words = action.lower().removeprefix("declare/undeclare ").removeprefix("undeclare ")
    words = words.removeprefix("declare ")
    return MESSAGE_NAMES.get(words, words.replace(" ", "_"))


def subjects_of(acl: Mapping[str, Any]) -> Callable[[str], int]:
    """How many subjects of the access control ``acl`` a session matches, from its trace name.

    The name is Zenoh's (``Interface(lo)+CertCommonName(cloud-b)+...``). A
    subject with no condition matches everyone; one with a list of
    certificate names or user names matches a session whose name is listed.
    """
    subjects = list(acl.get("subjects", ()))

    def count(name: str) -> int:
        found = {kind: set(pattern.findall(name)) for kind, pattern in _NAMED.items()}
        matched = 0
        for subject in subjects:
            conditions = [kind for kind in _NAMED if kind in subject]
            if all(found[kind] & set(subject[kind]) for kind in conditions):
                matched += 1
        return max(matched, 1)

    return count


def party_of(name: str) -> str:
    """Who a session is, from its trace name: its certificate's name, its login, or unknown."""
    for pattern in _NAMED.values():
        found = pattern.search(name)
        if found:
            return found.group(1)
    return "unknown"


@dataclass
class Refusal:
    """One message the router refused."""

    party: str  # the certificate's common name (or login) of the session that sent it
    session: str  # its Zenoh session id
    message: str  # the kind, as the access control names it (put, declare_queryable...)
    key: str


@dataclass
class _Thread:
    """Where the trace of one of Zenoh's threads stands."""

    group: tuple[str, str, str, str] | None = None  # (session, kind, flow, key)
    unauthorized: int = 0
    caching: str | None = None  # the flow of the block of cached decisions under way


@dataclass
class TraceReader:
    """Reads the access control's decisions out of Zenoh's trace lines, one line at a time."""

    subjects: Callable[[str], int]
    on_refusal: Callable[[Refusal], None]
    _threads: dict[str, _Thread] = field(default_factory=dict)
    _parties: dict[str, str] = field(default_factory=dict)  # session id -> party

    def line(self, text: str) -> bool:
        """Read one whole line of the trace (colours in); whether it was the access control's."""
        if self._allowed(text):
            return True
        found = _LINE.match(_ANSI.sub("", text, count=8))
        if found is None or found["target"] != ACL_TARGET:
            return False
        state = self._threads.setdefault(found["thread"], _Thread())
        body = found["body"]
        caching = _CACHING.match(body)
        if caching:
            state.caching, state.group = caching["flow"], None
            return True
        decision = _DECISION.match(body)
        if decision is None:
            return True
        zid, kind, flow = decision["zid"], message_name(decision["action"]), decision["flow"]
        refused = decision["verdict"] == "unauthorized"
        if decision["cached"]:
            # One line, the whole decision, after the block of cached ones.
            state.caching, state.group = None, None
            self._decided(zid, kind, flow, decision["key"], refused)
            return True
        subject = decision["subject"] or ""
        if len(self._parties) > 10_000:
            self._parties.clear()  # bounded: rebuilt from the next lines of each session
        self._parties[zid] = party_of(subject)
        group = (zid, kind, flow, decision["key"])
        if state.group != group:
            state.group, state.unauthorized = group, 0
        if refused:
            state.unauthorized += 1
            if state.unauthorized < self.subjects(subject):
                return True  # the next subject may allow it
        state.group = None
        if state.caching is not None:
            if kind == _LAST_CACHED and flow == state.caching:
                state.caching = None
            return True
        self._decided(zid, kind, flow, decision["key"], refused)
        return True

    def _allowed(self, text: str) -> bool:
        """The common line, an allowed message, read without the regular expressions.

        Most lines are: every message the router lets through writes one. Its
        only effect is to end its thread's group; a thread in a block of cached
        decisions, or a line of another kind, is left to ``line``. The verdict
        is the first one in the line: a key (after it) may hold the words.
        """
        allowed = text.find(_ALLOWED)
        if allowed < 0:
            return False
        refused = text.find(_REFUSED)
        if 0 <= refused < allowed or _ACL_MARK not in text:
            return False
        _, sep, rest = text.partition(_AFTER_LEVEL)
        thread, sep2, _ = rest.partition(_BEFORE_TARGET)
        if not sep or not sep2:
            return False
        state = self._threads.get(thread)
        if state is None or state.caching is not None:
            return False
        state.group = None
        return True

    def _decided(self, zid: str, kind: str, flow: str, key: str, refused: bool) -> None:
        if refused and flow == "ingress":
            debug = _DEBUG_KEY.match(key)
            key = debug["key"] if debug else key
            self.on_refusal(Refusal(self._parties.get(zid, "unknown"), zid, kind, key))


class RouterRefusals:
    """The refusals of one router: counted by (party, message), and logged."""

    def __init__(self, cloud: str) -> None:
        self.cloud = cloud
        self._lock = threading.Lock()
        self._counts: Counter[tuple[str, str]] = Counter()

    def refused(self, refusal: Refusal) -> None:
        with self._lock:
            self._counts[(refusal.party, refusal.message)] += 1
            count = self._counts[(refusal.party, refusal.message)]
        if count <= LOG_FIRST or count % 1000 == 0:
            logger.warning(
                "%s's router refused a %s on %r from %s (Zenoh session %s): its access "
                "control does not allow it (%s's refused %s messages so far: %d)",
                self.cloud,
                refusal.message,
                refusal.key,
                refusal.party,
                refusal.session,
                refusal.party,
                refusal.message,
                count,
            )

    def counts(self) -> dict[tuple[str, str], int]:
        """(party, message) -> how many were refused."""
        with self._lock:
            return dict(self._counts)


# -- reading the process's trace -------------------------------------------------

_watching: RouterRefusals | None = None
_F_SETPIPE_SZ = 1031  # Linux: a pipe of 1 MiB, so Zenoh's threads seldom wait on the reader


def watch(cloud: str, acl: Mapping[str, Any]) -> RouterRefusals:
    """Turn on Zenoh's access control trace and read it back for the router of ``cloud``.

    Call it once, before the router opens; the process's standard output is
    a pipe from then on (the module's docstring). A second call returns the
    first one's refusals.
    """
    global _watching
    if _watching is not None:
        return _watching
    import zenoh

    refusals = RouterRefusals(cloud)
    reader = TraceReader(subjects_of(acl), refusals.refused)
    try:
        real = _take_standard_output()
    except OSError as error:  # no standard output to take (closed): the router still enforces
        logger.warning(
            "the router's refusals will not be logged or counted: the standard output, where "
            "Zenoh writes its trace, cannot be read (%s)",
            error,
        )
        _watching = refusals
        return refusals
    thread = threading.Thread(
        target=_relay, args=(real.read_end, real.out, reader), name="zenoh-trace", daemon=True
    )
    thread.start()
    saved = {name: os.environ.pop(name, None) for name in ("RUST_LOG", "NO_COLOR")}
    try:
        # The trace of the access control only: nothing else of Zenoh's.
        zenoh.init_log_from_env_or(f"off,{ACL_TARGET}=trace")
    except Exception as error:  # whatever Zenoh says: the router still enforces its rules
        logger.warning(
            "the router's refusals will not be logged or counted: Zenoh's trace could not be "
            "turned on (%s)",
            error,
        )
    finally:
        for name, value in saved.items():
            if value is not None:
                os.environ[name] = value
    _watching = refusals
    return refusals


@dataclass
class _Pipe:
    read_end: int
    out: int  # the real standard output


def _take_standard_output() -> _Pipe:
    """Make file descriptor 1 a pipe; Python's ``sys.stdout`` keeps writing to the real one."""
    sys.stdout.flush()
    out = os.dup(1)
    read_end, write_end = os.pipe()
    with contextlib.suppress(OSError):  # a smaller pipe is slower, not wrong
        fcntl.fcntl(write_end, _F_SETPIPE_SZ, 1 << 20)
    os.dup2(write_end, 1)
    os.close(write_end)
    sys.stdout = io.TextIOWrapper(
        io.FileIO(out, "w", closefd=False), encoding="utf-8", line_buffering=True
    )
    return _Pipe(read_end, out)


def _relay(read_end: int, out: int, reader: TraceReader) -> None:
    """Read the pipe for ever: the access control's lines to ``reader``, the rest to ``out``.

    A line that does not start as Zenoh's own lines do is the rest of the
    line before it (a key with a newline): it is read with it. The last line
    is read when nothing more comes for 50 ms.
    """
    buffered = b""
    pending: bytes | None = None
    while True:
        ready, _, _ = select.select([read_end], [], [], 0.05)
        if not ready:
            if pending is not None:
                _one(pending, out, reader)
                pending = None
            continue
        chunk = os.read(read_end, 1 << 16)
        if not chunk:
            break
        buffered += chunk
        *lines, buffered = buffered.split(b"\n")
        for line in lines:
            if pending is not None and not line.startswith(_OWN_LINE):
                pending += b"\n" + line
                continue
            if pending is not None:
                _one(pending, out, reader)
            pending = line
    if pending is not None:
        _one(pending, out, reader)


def _one(line: bytes, out: int, reader: TraceReader) -> None:
    """One whole line: read it, or copy it to the real standard output if it is not the trace."""
    try:
        if reader.line(line.decode("utf-8", "replace")):
            return
    except Exception:  # never stop reading: Zenoh's threads would wait on a full pipe
        logger.exception("a line of Zenoh's trace could not be read")
        return
    data = line + b"\n"
    while data:
        try:
            data = data[os.write(out, data) :]
        except OSError:
            return
