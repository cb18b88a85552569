"""``robocloud ros2``: the ROS 2 gateway, from the command line.

::

    robocloud ros2 --cloud cloud-a --connect tcp/127.0.0.1:7447 --robots robots.json \\
                   [--gateway-name ros2]

It runs until interrupted (Ctrl-C or SIGTERM). Every argument is checked, and
the robots file read, before anything is opened.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from typing import TYPE_CHECKING

from robocloud.federation import security
from robocloud.gateways.ros2.robots_file import RobotsFile, load_robots

if TYPE_CHECKING:
    from robocloud.gateways.zenoh_side import CommandHandler, RobotSide


def add_ros2_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cloud", required=True, help="the cloud the robots join, e.g. cloud-a")
    parser.add_argument(
        "--connect",
        required=True,
        action="append",
        metavar="ZENOH_ENDPOINT",
        help="the IaaS's Zenoh router, e.g. tcp/127.0.0.1:7447 (repeat for fallbacks)",
    )
    parser.add_argument(
        "--robots",
        required=True,
        metavar="FILE",
        help="JSON: each robot's endpoint, scheme, domain, namespace, distro, offset, speed "
        "and capabilities (docs/ros2.md)",
    )
    parser.add_argument(
        "--gateway-name",
        default="ros2",
        metavar="NAME",
        help="the fleet gateway's name: the states go to robocloud/<cloud>/fleets/NAME/states "
        "(default ros2)",
    )
    parser.add_argument(
        "--robot-keys",
        action="store_true",
        help="speak on each robot's own keys (a state publisher and a command queryable "
        "each) instead of as a fleet gateway: what `robocloud robot-check` reads",
    )
    parser.add_argument(
        "--connect-timeout",
        type=float,
        default=10.0,
        metavar="SECONDS",
        help="how long to wait for the cloud's router (default 10); robots are waited for "
        "as long as it takes",
    )
    parser.add_argument(
        "--log-level",
        default="info",
        choices=("debug", "info", "warning", "error"),
        help="default info",
    )
    security.add_arguments(parser, router=False)


def check_arguments(args: argparse.Namespace) -> RobotsFile:
    """Everything the gateway would refuse, before it opens anything."""
    from robocloud.cli.iaas_command import check_endpoints
    from robocloud.errors import InvalidInput
    from robocloud.fleet.keys import check_chunk

    check_chunk(args.cloud, "--cloud")
    check_chunk(args.gateway_name, "--gateway-name")
    check_endpoints(args.connect, "--connect")
    if not 0 <= args.connect_timeout <= 3600:  # also refuses nan
        raise InvalidInput(
            f"--connect-timeout must be 0 to 3600 s, not {args.connect_timeout}.",
            "--connect-timeout",
        )
    security.from_arguments(args)
    robots = load_robots(args.robots)
    for robot, entry in robots.robots.items():
        check_chunk(robot, "robot id")
        check_endpoints([entry.endpoint], f"{args.robots}: robots.{robot}.endpoint")
    return robots


def ros2_command(args: argparse.Namespace) -> int:
    """Run the gateway until SIGINT or SIGTERM; 0 when it stopped cleanly."""
    robots = check_arguments(args)
    logging.basicConfig(
        level=args.log_level.upper(),
        format=f"%(asctime)s {args.cloud}-ros2 %(levelname)s %(name)s: %(message)s",
    )
    stop = threading.Event()
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for signum in (signal.SIGINT, signal.SIGTERM):
            previous[signum] = signal.signal(signum, lambda *_: stop.set())
    try:
        run_gateway(args, robots, stop)
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    return 0


def run_gateway(args: argparse.Namespace, robots: RobotsFile, stop: threading.Event) -> None:
    from robocloud.fleet.zenoh_session import open_client
    from robocloud.gateways.ros2.gateway import Ros2Gateway
    from robocloud.gateways.zenoh_side import ZenohFleet, ZenohRobots

    session = open_client(
        args.connect, timeout=args.connect_timeout, security=security.from_arguments(args)
    )
    try:

        def fleet(on_command: CommandHandler) -> RobotSide:
            if args.robot_keys:
                return ZenohRobots(session, args.cloud, on_command)
            return ZenohFleet(session, args.cloud, args.gateway_name, on_command)

        gateway = Ros2Gateway(fleet, robots)
        gateway.start()
        print(
            f"ROS 2 gateway: {len(robots.robots)} robots of {args.robots} are robots of "
            f"{args.cloud} at {', '.join(args.connect)} "
            f"({'robot keys' if args.robot_keys else 'fleet ' + args.gateway_name}); Ctrl-C stops",
            file=sys.stderr,
            flush=True,
        )
        try:
            stop.wait()
        finally:
            gateway.stop()
    finally:
        session.close()  # type: ignore[no-untyped-call]
