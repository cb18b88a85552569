"""``make run``'s plan, its restart requests and its banner, without starting anything."""

from __future__ import annotations

import argparse
import queue
import shlex
import threading
from pathlib import Path

import pytest

from robocloud.cli import demo


def args(*argv: str) -> argparse.Namespace:
    return demo.parse_args(list(argv))


def test_the_plan_starts_each_iaas_then_each_simulator_then_the_page(tmp_path: Path) -> None:
    members, parts = demo.plan(args("--robots", "100", "--var", str(tmp_path)), "k3y")
    assert [m.robots for m in members] == [34, 33, 33]
    assert [p.title for p in parts] == [
        "cloud-a's IaaS", "cloud-b's IaaS", "cloud-c's IaaS",
        "cloud-a's simulator", "cloud-b's simulator", "cloud-c's simulator",
        "the Wildfire Suppression Application",
    ]
    c = parts[2]
    assert c.argv[c.argv.index("--store") + 1] == f"sqlite:///{tmp_path / 'cloud-c.db'}"
    # Each cloud joins the ones before it.
    assert [c.argv[i + 1] for i, a in enumerate(c.argv) if a == "--peer"] == [
        "tcp/127.0.0.1:7447", "tcp/127.0.0.1:7448"
    ]
    assert c.env == {"ROBOCLOUD_API_KEYS": "demo=k3y"} and c.health is not None
    assert parts[-1].env == {"ROBOCLOUD_WILDFIRE_API_KEY": "k3y"}


def test_the_command_by_hand_is_a_shell_command_that_parses_as_the_part(tmp_path: Path) -> None:
    _, parts = demo.plan(args("--var", str(tmp_path / "a dir")), "k 3")
    words = shlex.split(parts[1].by_hand())
    assert words[0] == "ROBOCLOUD_API_KEYS=demo=k 3"
    assert words[-len(parts[1].argv):] == parts[1].argv
    assert "robocloud" in words[1]


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--clouds", "0"], "--clouds must be between 1 and 26"),
        (["--clouds", "27"], "--clouds must be between 1 and 26"),
        (["--clouds", "3", "--robots", "2"], "--robots must be at least one per cloud"),
        (["--speedup", "0"], "--speedup must be more than 0"),
        (["--speedup", "nan"], "--speedup must be more than 0"),
        (["--http-port", "65534"], "--http-port 65534"),
        (["--zenoh-port", "0"], "--zenoh-port 0"),
    ],
)
def test_bad_options_are_a_usage_error(
    capsys: pytest.CaptureFixture[str], argv: list[str], words: str
) -> None:
    with pytest.raises(SystemExit) as stopped:
        args(*argv)
    assert stopped.value.code == 2
    assert words in capsys.readouterr().err


def test_what_to_restart(capsys: pytest.CaptureFixture[str]) -> None:
    _, parts = demo.plan(args(), "k")
    asked: queue.SimpleQueue[str] = queue.SimpleQueue()
    signalled = threading.Event()
    assert demo._wanted(asked, signalled, parts) is None
    signalled.set()
    assert demo._wanted(asked, signalled, parts) == set()  # kill -USR1: all that stopped
    assert not signalled.is_set()
    for line, wanted in [("", set()), ("cloud-b", {"cloud-b"}), ("c", {"cloud-c"}),
                         ("wildfire", {"wildfire"}), ("cloud-z", None)]:
        asked.put(line)
        assert demo._wanted(asked, signalled, parts) == wanted
    assert "'cloud-z' is not a cloud here" in capsys.readouterr().err


def test_the_banner_says_where_state_lives_and_how_to_see_every_cloud() -> None:
    options = args()
    members, parts = demo.plan(options, "k")
    banner = demo._banner(members, parts, "k", options, interactive=False)
    assert "State: stores and logs in var/" in banner and "`make reset`" in banner
    assert "/v1/robots?scope=federation" in banner
    assert "kill -USR1" in banner and "press Enter" not in banner
    assert "press Enter" in demo._banner(members, parts, "k", options, interactive=True)
    elsewhere = args("--var", "/tmp/robocloud-demo")
    banner = demo._banner(*demo.plan(elsewhere, "k"), "k", elsewhere, interactive=False)
    assert "`rm -rf /tmp/robocloud-demo`" in banner
