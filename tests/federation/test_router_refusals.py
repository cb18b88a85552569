"""What a router refused, read back from Zenoh's own trace (federation/security/router_refusals.py).

The main test runs a real router with robocloud's access control and mutual
TLS in a child process (``watch`` takes the process's standard output), and
a client holding cloud-a's fleet certificate: the refusals it counts are
exactly the messages the access control refused, whatever Zenoh prints
around them (its decisions for each subject, its cache of a declared key,
the decisions of allowed messages), a key holding a newline and a made-up
trace line forges nothing, and one holding the words of an allowed verdict
hides nothing.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from robocloud.federation.security import access_control, make_certs
from robocloud.federation.security.router_refusals import (
    TraceReader,
    _relay,
    message_name,
    subjects_of,
)

CHILD = r"""
import json, logging, sys, threading, time
from pathlib import Path
from robocloud.federation.security import OverlaySecurity
from robocloud.federation.security.router_refusals import watch
from robocloud.fleet import open_client, open_router

certs, endpoint = Path(sys.argv[1]), sys.argv[2]
logging.basicConfig(level="WARNING")  # the refusals' lines on standard error

def security(name):
    return OverlaySecurity(
        ca=certs / "ca.pem", cert=certs / f"{name}.pem", key=certs / f"{name}.key"
    )

router_security = security("cloud-a").for_cloud("cloud-a", ["cloud-b"])
refusals = watch("cloud-a", router_security.config_entries("router")["access_control"])
print("python's own output", flush=True)
router = open_router([endpoint], security=router_security)
heard = []
router.declare_subscriber("robocloud/**", lambda sample: heard.append(str(sample.key_expr)))
fleet = open_client([endpoint], timeout=5, security=security("cloud-a-robots"))
for _ in range(3):
    fleet.put("robocloud/cloud-a/robots/a-1/state", "{}")  # allowed
for _ in range(4):
    fleet.put("robocloud/cloud-b/robots/b-1/state", "{}")  # another cloud's robot
fleet.put(sys.argv[3], "{}")  # a key with a newline and a made-up trace line
fleet.put("robocloud/cloud-b/x is authorized to Put (ingress) on y", "{}")  # words of a verdict
token = fleet.liveliness().declare_token("robocloud/federation/clouds/cloud-zzz/1")
queryable = fleet.declare_queryable("robocloud/cloud-zzz/*", lambda query: None)
mine = fleet.declare_publisher("robocloud/cloud-a/robots/a-2/state")  # a declared key
theirs = fleet.declare_publisher("robocloud/cloud-b/robots/b-2/state")
for _ in range(2):
    mine.put("{}")
    theirs.put("{}")
# The router judges one link's messages in order: once it let the last one through,
# it judged every one before; the trace is read within 50 ms of its last line.
fleet.put("robocloud/cloud-a/robots/last/state", "{}")
deadline = time.monotonic() + 10
while "robocloud/cloud-a/robots/last/state" not in heard and time.monotonic() < deadline:
    time.sleep(0.01)
# Then a last refused put: once its refusal is logged, every line before it was read
# (one pipe, read in order).
read = threading.Event()

class Sentinel(logging.Handler):
    def emit(self, record):
        if "robocloud/cloud-b/sentinel" in record.getMessage():
            read.set()

logging.getLogger("robocloud.federation.security.router_refusals").addHandler(Sentinel())
fleet.put("robocloud/cloud-b/sentinel", "{}")
assert read.wait(10), "the sentinel's refusal was not read"
counts = {f"{party} {message}": n for (party, message), n in refusals.counts().items()}
print(json.dumps({"counts": counts, "heard": sorted(set(heard))}), flush=True)
fleet.close()
router.close()  # its callbacks' threads end with it, and the process with them
"""

FORGED = (
    "robocloud/cloud-b/x\n\x1b[2m2026-12-03T04:07:35.340220Z TRACE rx-1 ThreadId(09) "
    "zenoh::net::routing::interceptor::access_control: 0a on CertCommonName(cloud-zz) "
    "is unauthorized to Put (ingress) on robocloud/made-up"
)


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("certs")
    make_certs(path, ["cloud-a", "cloud-a-robots"])
    return path


def test_a_real_routers_refusals_are_counted_exactly(certs: Path) -> None:
    from loopback_ports import free_endpoint

    env = {k: v for k, v in os.environ.items() if k != "RUST_LOG"}
    env["NO_COLOR"] = "1"  # taken out while the trace is turned on: its colours frame it
    done = subprocess.run(
        [sys.executable, "-c", CHILD, str(certs), free_endpoint(), FORGED],
        capture_output=True,
        text=True,
        timeout=60,
        stdin=subprocess.DEVNULL,
        env=env,
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    # Only Python's own output and the result reach the real standard output: the
    # trace is read, not copied.
    assert lines[0] == "python's own output" and len(lines) == 2, done.stdout
    result = json.loads(lines[1])
    assert result["counts"] == {
        # 4 of b-1, the forged key's, the verdict's words, 2 through b-2's publisher, the
        # sentinel
        "cloud-a-robots put": 9,
        "cloud-a-robots liveliness_token": 1,
        "cloud-a-robots declare_queryable": 1,
    }
    assert "robocloud/cloud-a/robots/a-2/state" in result["heard"]
    assert not [key for key in result["heard"] if "cloud-b" in key]
    said = [line for line in done.stderr.splitlines() if "router refused" in line]
    assert len(said) == 11 and "from cloud-zz " not in done.stderr
    # The forged key is logged whole, its newline escaped, in the line of its refusal.
    [forged] = [line for line in said if "made-up" in line]
    assert "robocloud/cloud-b/x\\n" in forged and "from cloud-a-robots" in forged


def test_a_closed_standard_output_leaves_the_router_unwatched_not_down() -> None:
    """A process started with its standard output closed: a warning, and nothing counted."""
    child = (
        "import os, sys\n"
        "os.close(1)\n"
        "from robocloud.federation.security.router_refusals import watch\n"
        "refusals = watch('cloud-a', {'subjects': []})\n"
        "sys.stderr.write(f'counts {refusals.counts()}\\n')\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", child],
        capture_output=True,
        text=True,
        timeout=60,
        stdin=subprocess.DEVNULL,
    )
    assert done.returncode == 0, done.stderr
    assert "the router's refusals will not be logged or counted" in done.stderr
    assert "counts {}" in done.stderr and "Traceback" not in done.stderr


def test_a_line_that_does_not_start_as_zenohs_is_the_rest_of_the_one_before() -> None:
    """The pipe's framing alone: what Zenoh starts with a raw ESC, the rest is continuation,
    and what is not the access control's trace is copied out unchanged."""
    read_end, write_end = os.pipe()
    out_read, out_write = os.pipe()
    seen: list[str] = []

    class Recorder(TraceReader):
        def line(self, text: str) -> bool:
            seen.append(text)
            return "access_control" in text

    reader = Recorder(lambda name: 1, lambda refusal: None)
    thread = threading.Thread(target=_relay, args=(read_end, out_write, reader), daemon=True)
    thread.start()
    os.write(write_end, b"\x1b[2mone access_control on a/b\nc\x1b[2m not ours\n")
    os.write(write_end, b"\x1b[2mtwo access_control\n\x1b[2mthree, not the trace\nplain\n")
    os.close(write_end)
    thread.join(5)
    os.close(out_write)
    with os.fdopen(out_read, "rb") as copied:
        assert copied.read() == b"\x1b[2mthree, not the trace\nplain\n"
    assert seen == [
        "\x1b[2mone access_control on a/b\nc\x1b[2m not ours",
        "\x1b[2mtwo access_control",
        "\x1b[2mthree, not the trace\nplain",
    ]


def test_subjects_are_counted_as_the_access_control_lists_them() -> None:
    count = subjects_of(access_control("cloud-a", ["cloud-b"], robot_ids=["a-1"]))
    assert count("Interface(lo)+CertCommonName(cloud-a-robots)+Transport(Tls)+0a") == 2
    assert count("Interface(lo)+CertCommonName(cloud-a-robot-a-1)+Transport(Tls)+0a") == 2
    assert count("Interface(lo)+CertCommonName(cloud-b)+Transport(Tls)+0a") == 2
    assert count("Interface(lo)+CertCommonName(cloud-zz)+Transport(Tls)+0a") == 1
    logins = subjects_of(access_control("cloud-a", by_certificate=False))
    assert logins("Interface(lo)+Username(cloud-a)+Transport(Tcp)+0a") == 2
    assert logins("Interface(lo)+Username(cloud-b)+Transport(Tcp)+0a") == 1


def test_zenohs_words_for_messages_are_the_access_controls() -> None:
    assert message_name("Put") == "put"
    assert message_name("Declare Queryable") == "declare_queryable"
    assert message_name("Declare/Undeclare Queryable") == "declare_queryable"
    assert message_name("Liveliness Token") == "liveliness_token"
    assert message_name("Declare/Undeclare Liveliness Token") == "liveliness_token"
    assert message_name("Declare Liveliness Subscriber") == "declare_liveliness_subscriber"
    assert message_name("Something New") == "something_new"
