"""``robocloud ros2``: the ROS 2 gateway, from the command line.

::

    robocloud ros2 --cloud cloud-a --connect tcp/127.0.0.1:7447 --robots robots.json \\
                   [--gateway-name ros2]

It runs until interrupted (Ctrl-C or SIGTERM). Every argument is checked, and
the robots file read, before anything is opened.
"""

from __future__ import annotations

import argparse
import threading

from robocloud.gateways import command_common as common
from robocloud.gateways.ros2.robots_file import RobotsFile, load_robots


def add_ros2_arguments(parser: argparse.ArgumentParser) -> None:
    common.add_common_arguments(
        parser,
        "the robots",
        "the cloud's router (default 10); robots are waited for as long as it takes",
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


def check_arguments(args: argparse.Namespace) -> RobotsFile:
    """Everything the gateway would refuse, before it opens anything."""
    from robocloud.fleet.keys import check_chunk
    from robocloud.fleet.zenoh_session import check_endpoints

    common.check_common(args, args.gateway_name)
    robots = load_robots(args.robots)
    for robot, entry in robots.robots.items():
        check_chunk(robot, "robot id")
        check_endpoints([entry.endpoint], f"{args.robots}: robots.{robot}.endpoint")
    return robots


def ros2_command(args: argparse.Namespace) -> int:
    """Run the gateway until SIGINT or SIGTERM; 0 when it stopped cleanly."""
    robots = check_arguments(args)
    return common.run_until_stopped(args, "ros2", lambda stop: run_gateway(args, robots, stop))


def run_gateway(args: argparse.Namespace, robots: RobotsFile, stop: threading.Event) -> None:
    from robocloud.gateways.ros2.gateway import Ros2Gateway

    with common.zenoh_client(args) as session:
        name = None if args.robot_keys else args.gateway_name
        gateway = Ros2Gateway(common.robot_side(session, args.cloud, name), robots)
        gateway.start()
        try:
            common.wait_until_stopped(
                stop,
                f"ROS 2 gateway: {len(robots.robots)} robots of {args.robots} are robots of "
                f"{args.cloud} at {', '.join(args.connect)} "
                f"({'robot keys' if args.robot_keys else 'fleet ' + args.gateway_name})",
            )
        finally:
            gateway.stop()
