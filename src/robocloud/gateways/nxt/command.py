"""``robocloud nxt``: the NXT gateway, from the command line (and ``robocloud nxt-brick``).

::

    robocloud nxt --cloud cloud-a --connect tcp/127.0.0.1:7447 --bricks bricks.json \\
                  [--gateway-name NAME]
    robocloud nxt-brick --bricks bricks.json --robot tribot [--speedup 10] [--obstacle 1,0]

It runs until interrupted (Ctrl-C or SIGTERM). Every argument is checked, and
the bricks file read, before anything is opened.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from typing import TYPE_CHECKING

from robocloud.errors import InvalidInput
from robocloud.federation import security
from robocloud.gateways.nxt.bricks import BricksFile, load_bricks

if TYPE_CHECKING:
    from robocloud.gateways.zenoh_side import CommandHandler, RobotSide


def add_nxt_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cloud", required=True, help="the cloud the bricks join, e.g. cloud-a")
    parser.add_argument(
        "--connect",
        required=True,
        action="append",
        metavar="ZENOH_ENDPOINT",
        help="the IaaS's Zenoh router, e.g. tcp/127.0.0.1:7447 (repeat for fallbacks)",
    )
    parser.add_argument(
        "--bricks",
        required=True,
        metavar="FILE",
        help="JSON: each robot's brick (Bluetooth address or a stand-in's host:port), build, "
        "sensors, start pose and capabilities (docs/nxt.md)",
    )
    parser.add_argument(
        "--gateway-name",
        metavar="NAME",
        help="speak for the bricks as a fleet gateway named NAME: one command queryable for "
        "all and their states on robocloud/<cloud>/fleets/NAME/states (default: the keys "
        "of a robot for each brick)",
    )
    parser.add_argument(
        "--connect-timeout",
        type=float,
        default=10.0,
        metavar="SECONDS",
        help="how long to wait for the router (default 10)",
    )
    parser.add_argument(
        "--log-level",
        default="info",
        choices=("debug", "info", "warning", "error"),
        help="default info; debug also shows the traceback of an error",
    )
    security.add_arguments(parser, router=False)


def check_arguments(args: argparse.Namespace) -> BricksFile:
    """Everything the gateway would refuse, before it opens anything."""
    from robocloud.cli.iaas_command import check_endpoints
    from robocloud.fleet.keys import check_chunk

    check_chunk(args.cloud, "--cloud")
    if args.gateway_name is not None:
        check_chunk(args.gateway_name, "--gateway-name")
    check_endpoints(args.connect, "--connect")
    if not 0 <= args.connect_timeout <= 3600:  # also refuses nan
        raise InvalidInput(
            f"--connect-timeout must be 0 to 3600 s, not {args.connect_timeout}.",
            "--connect-timeout",
        )
    security.from_arguments(args)
    return load_bricks(args.bricks)


def nxt_command(args: argparse.Namespace) -> int:
    """Run the gateway until SIGINT or SIGTERM; 0 when it stopped cleanly."""
    bricks = check_arguments(args)
    logging.basicConfig(
        level=args.log_level.upper(),
        format=f"%(asctime)s {args.cloud}-nxt %(levelname)s %(name)s: %(message)s",
    )
    stop = threading.Event()
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for signum in (signal.SIGINT, signal.SIGTERM):
            previous[signum] = signal.signal(signum, lambda *_: stop.set())
    try:
        run_gateway(args, bricks, stop)
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    return 0


def run_gateway(args: argparse.Namespace, bricks: BricksFile, stop: threading.Event) -> None:
    from robocloud.fleet.zenoh_session import open_client
    from robocloud.gateways.nxt.gateway import NxtGateway
    from robocloud.gateways.zenoh_side import ZenohFleet, ZenohRobots

    session = open_client(
        args.connect, timeout=args.connect_timeout, security=security.from_arguments(args)
    )
    try:
        name = args.gateway_name

        def robot_side(on_command: CommandHandler) -> RobotSide:
            if name is None:
                return ZenohRobots(session, args.cloud, on_command)
            return ZenohFleet(session, args.cloud, name, on_command)

        with NxtGateway(robot_side, bricks):
            print(
                f"NXT gateway: {len(bricks.robots)} brick{'s' if len(bricks.robots) > 1 else ''} "
                f"({', '.join(bricks.robots)}) as robots of {args.cloud} at "
                f"{', '.join(args.connect)}; Ctrl-C stops",
                file=sys.stderr,
                flush=True,
            )
            stop.wait()
    finally:
        session.close()  # type: ignore[no-untyped-call]
