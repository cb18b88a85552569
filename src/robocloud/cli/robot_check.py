"""``robocloud robot-check``: the robot protocol's conformance kit, as a command.

::

    robocloud robot-check --connect tcp/127.0.0.1:7447 --cloud cloud-a --robot ex-1

The kit is a stand-in IaaS (``robocloud.conformance.kit``): a Zenoh router
listening on ``--connect``, the endpoint the robot connects to (``--client``:
a client of a router already there). It drives the robot through every rule
of docs/protocol.md and prints a table, one line and one sentence per rule.
Exit 0 when every rule passed, 1 when one failed, 2 for a wrong argument.
"""

from __future__ import annotations

import argparse
import logging
import sys

from robocloud.conformance.rules import Timing
from robocloud.errors import InvalidInput

EXIT_PASSED = 0
EXIT_FAILED = 1

# The kit's waits (rules.Timing): the defaults are docs/protocol.md's, for a real
# robot; a robot quick to observe (a simulator at a speed-up) may be given shorter.
TIMING_OPTIONS: tuple[tuple[str, float, str], ...] = (
    ("--ack-timeout", Timing.ack_timeout, "the deadline for an ack, as the IaaS's --ack-timeout"),
    ("--join-timeout", Timing.join_timeout, "how long to wait for the robot's first state"),
    ("--task-timeout", Timing.task_timeout, "the longest the kit waits for a task to end"),
    ("--outage", Timing.outage, "how long the kit stays away in the reconnect rule"),
    (
        "--reconnect-timeout",
        Timing.reconnect_timeout,
        "how long the kit waits for a state after the outage",
    ),
    (
        "--overrun-min",
        Timing.overrun_min,
        "the watchdog's least tolerance past a task's expected time, as the IaaS's --overrun-min",
    ),
    ("--travel", Timing.travel, "seconds of travel, at the robot's speed, of the kit's tasks"),
    (
        "--report-within",
        Timing.report_within,
        "the deadline for a state that shows a command's change (a new task, a stop)",
    ),
    (
        "--watch",
        Timing.watch,
        "how long the kit watches, after a cancel or a refused command, that the robot does "
        "not work on the request",
    ),
    ("--linger", Timing.linger, "how long the kit watches last_task after a task ended"),
    (
        "--clean-within",
        Timing.clean_within,
        "the deadline for a robot told to cancel to be idle before the next scenario",
    ),
)


def add_robot_check_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--connect",
        required=True,
        metavar="ENDPOINT",
        help="the endpoint the robot connects to, e.g. tcp/127.0.0.1:7447; the kit listens "
        "there as a Zenoh router, as the IaaS would",
    )
    parser.add_argument("--cloud", required=True, help="the robot's cloud, e.g. cloud-a")
    parser.add_argument("--robot", required=True, metavar="ID", help="the robot's id")
    parser.add_argument(
        "--client",
        action="store_true",
        help="connect to a router already at ENDPOINT as a client instead of being the router",
    )
    parser.add_argument(
        "--capability",
        metavar="NAME",
        help="the capability the kit's tasks use (default: the robot's quickest)",
    )
    for flag, default, what in TIMING_OPTIONS:
        parser.add_argument(
            flag,
            type=float,
            default=default,
            metavar="SECONDS",
            help=f"{what} (default {default:g})",
        )
    parser.add_argument(
        "--log-level",
        default="warning",
        choices=("debug", "info", "warning", "error"),
        help="default warning; info also prints each rule as it starts",
    )


def robot_check_command(args: argparse.Namespace) -> int:
    from robocloud.conformance import RobotCheck
    from robocloud.fleet.keys import check_chunk
    from robocloud.fleet.zenoh_session import check_endpoints

    check_chunk(args.cloud, "--cloud")
    check_chunk(args.robot, "--robot")
    check_endpoints([args.connect], "--connect")
    for name, _, _ in TIMING_OPTIONS:
        value = getattr(args, _field(name))
        if not 0 < value <= 3600:  # also refuses nan
            raise InvalidInput(f"{name} must be more than 0 and at most 3600, not {value}.", name)
    logging.basicConfig(
        level=args.log_level.upper(), format="robot-check %(levelname)s: %(message)s"
    )
    verbose = args.log_level in ("debug", "info")
    check = RobotCheck(
        args.connect,
        args.cloud,
        args.robot,
        client=args.client,
        timing=Timing(
            **{_field(name): getattr(args, _field(name)) for name, _, _ in TIMING_OPTIONS}
        ),
        capability=args.capability,
        progress=say_on_stderr if verbose else say_nothing,
    )
    mode = "as a client of" if args.client else "listening on"
    print(
        f"robot-check: robot {args.robot} of {args.cloud}, the kit {mode} {args.connect}",
        flush=True,
    )
    results = check.run()
    width = max(len(r.rule) for r in results)
    for result in results:
        mark = "pass" if result.passed else "FAIL"
        print(f"{result.rule:<{width}}  {mark}  {result.sentence}")
    failed = sum(not r.passed for r in results)
    print(f"{len(results) - failed} passed, {failed} failed")
    return EXIT_FAILED if failed else EXIT_PASSED


def _field(flag: str) -> str:
    """The Timing field of an option: --report-within, report_within."""
    return flag.removeprefix("--").replace("-", "_")


def say_on_stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def say_nothing(line: str) -> None:
    del line
