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
import threading

from robocloud.gateways import command_common as common
from robocloud.gateways.nxt.bricks import BricksFile, load_bricks


def add_nxt_arguments(parser: argparse.ArgumentParser) -> None:
    common.add_common_arguments(parser, "the bricks")
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
        help="speak for the bricks as a fleet gateway named NAME: a command queryable per "
        "brick and their states on robocloud/<cloud>/fleets/NAME/states (default: the keys "
        "of a robot for each brick)",
    )


def check_arguments(args: argparse.Namespace) -> BricksFile:
    """Everything the gateway would refuse, before it opens anything."""
    common.check_common(args, args.gateway_name)
    return load_bricks(args.bricks)


def nxt_command(args: argparse.Namespace) -> int:
    """Run the gateway until SIGINT or SIGTERM; 0 when it stopped cleanly."""
    bricks = check_arguments(args)
    return common.run_until_stopped(args, "nxt", lambda stop: run_gateway(args, bricks, stop))


def run_gateway(args: argparse.Namespace, bricks: BricksFile, stop: threading.Event) -> None:
    from robocloud.gateways.nxt.gateway import NxtGateway

    with (
        common.zenoh_client(args) as session,
        NxtGateway(common.robot_side(session, args.cloud, args.gateway_name), bricks),
    ):
        common.wait_until_stopped(
            stop,
            f"NXT gateway: {len(bricks.robots)} brick{'s' if len(bricks.robots) > 1 else ''} "
            f"({', '.join(bricks.robots)}) as robots of {args.cloud} at "
            f"{', '.join(args.connect)}",
        )
