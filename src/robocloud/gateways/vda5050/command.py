"""``robocloud vda5050``: the VDA 5050 gateway, from the command line.

::

    robocloud vda5050 --cloud cloud-a --connect tcp/127.0.0.1:7447 --mqtt 127.0.0.1:1883 \\
                      [--interface uagv] [--major v2] [--capabilities agvs.json] \\
                      [--accept-within 5] [--reconcile-grace 5] [--state-interval 10] \\
                      [--metrics 9102]

It runs until interrupted (Ctrl-C or SIGTERM). Every argument is checked, and
the capabilities file read, before anything is opened.
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
from robocloud.gateways.vda5050.agv import Timing
from robocloud.gateways.vda5050.capabilities import GatewayCapabilities, load_capabilities
from robocloud.gateways.vda5050.messages import MAJOR
from robocloud.sim.metrics import metrics_address

if TYPE_CHECKING:
    from robocloud.gateways.zenoh_side import CommandHandler

DEFAULT_MQTT = "127.0.0.1:1883"


def add_vda5050_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cloud", required=True, help="the cloud the AGVs join, e.g. cloud-a")
    parser.add_argument(
        "--connect",
        required=True,
        action="append",
        metavar="ZENOH_ENDPOINT",
        help="the IaaS's Zenoh router, e.g. tcp/127.0.0.1:7447 (repeat for fallbacks)",
    )
    parser.add_argument(
        "--mqtt",
        default=DEFAULT_MQTT,
        metavar="HOST:PORT",
        help=f"the MQTT broker of the AGVs (default {DEFAULT_MQTT})",
    )
    parser.add_argument(
        "--interface", default="uagv", help="the first level of the AGVs' topics (default uagv)"
    )
    parser.add_argument(
        "--major", default=MAJOR, help=f"the topics' major version: only {MAJOR} is spoken"
    )
    parser.add_argument(
        "--capabilities",
        metavar="FILE",
        help="JSON: capability -> VDA 5050 action, kind, time, cost (without it no AGV "
        "has a capability, so none is chosen)",
    )
    parser.add_argument(
        "--connect-timeout",
        type=float,
        default=10.0,
        metavar="SECONDS",
        help="how long to wait for the router and the broker (default 10)",
    )
    parser.add_argument(
        "--log-level",
        default="info",
        choices=("debug", "info", "warning", "error"),
        help="default info; debug also shows the traceback of an error",
    )
    parser.add_argument(
        "--gateway-name",
        metavar="NAME",
        help="speak for the AGVs as a fleet gateway named NAME: one command queryable for "
        "all and their states on robocloud/<cloud>/fleets/NAME/states (default: the keys "
        "of a robot for each AGV)",
    )
    defaults = Timing()
    parser.add_argument(
        "--accept-within",
        type=float,
        default=defaults.accept_within,
        metavar="SECONDS",
        help="an order whose orderId and orderUpdateId the AGV's state has not shown within "
        f"this time is cancelled and its task failed (default {defaults.accept_within:g})",
    )
    parser.add_argument(
        "--reconcile-grace",
        type=float,
        default=defaults.reconcile_grace,
        metavar="SECONDS",
        help="an AGV found on a robocloud order this gateway did not send gets cancelOrder "
        "unless the IaaS assigns that request to it within this time (default "
        f"{defaults.reconcile_grace:g})",
    )
    parser.add_argument(
        "--state-interval",
        type=float,
        default=defaults.state_interval,
        metavar="SECONDS",
        help="an AGV's state interval when its factsheet has no defaultStateInterval; silent "
        f"for {defaults.silent_intervals:g} intervals (at most {defaults.max_silence:g} s) it "
        f"is offline (default {defaults.state_interval:g})",
    )
    parser.add_argument(
        "--metrics",
        type=metrics_address,
        metavar="HOST:PORT",
        help="serve Prometheus metrics at http://HOST:PORT/metrics (docs/metrics.md)",
    )
    security.add_arguments(parser, router=False)


def mqtt_address(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise InvalidInput(f"--mqtt {text!r} is not HOST:PORT, e.g. {DEFAULT_MQTT}.", "--mqtt")
    return host.strip("[]"), int(port)


def topic_level(text: str, flag: str) -> str:
    if not text or any(ch in text for ch in "/+#") or text != text.strip():
        raise InvalidInput(
            f"{flag} {text!r} must be one MQTT topic level: not empty, without / + or #.", flag
        )
    return text


def check_arguments(args: argparse.Namespace) -> tuple[tuple[str, int], GatewayCapabilities]:
    """Everything the gateway would refuse, before it opens anything."""
    from robocloud.cli.iaas_command import check_endpoints
    from robocloud.fleet.keys import check_chunk

    check_chunk(args.cloud, "--cloud")
    if args.gateway_name is not None:
        check_chunk(args.gateway_name, "--gateway-name")
    check_endpoints(args.connect, "--connect")
    address = mqtt_address(args.mqtt)
    topic_level(args.interface, "--interface")
    if args.major != MAJOR:
        raise InvalidInput(
            f"--major {args.major!r} is not spoken: the gateway speaks VDA 5050 2.x ({MAJOR}).",
            "--major",
        )
    if not 0 <= args.connect_timeout <= 3600:  # also refuses nan
        raise InvalidInput(
            f"--connect-timeout must be 0 to 3600 s, not {args.connect_timeout}.",
            "--connect-timeout",
        )
    for flag, value, top in (
        ("--accept-within", args.accept_within, 600.0),
        ("--reconcile-grace", args.reconcile_grace, 600.0),
        ("--state-interval", args.state_interval, 30.0),
    ):
        if not 0 < value <= top:  # also refuses nan
            raise InvalidInput(
                f"{flag} must be more than 0 and at most {top:g} s, not {value}.", flag
            )
    security.from_arguments(args)
    return address, load_capabilities(args.capabilities)


def timing(args: argparse.Namespace) -> Timing:
    return Timing(
        accept_within=args.accept_within,
        reconcile_grace=args.reconcile_grace,
        state_interval=args.state_interval,
    )


def vda5050_command(args: argparse.Namespace) -> int:
    """Run the gateway until SIGINT or SIGTERM; 0 when it stopped cleanly."""
    address, capabilities = check_arguments(args)
    logging.basicConfig(
        level=args.log_level.upper(),
        format=f"%(asctime)s {args.cloud}-vda5050 %(levelname)s %(name)s: %(message)s",
    )
    stop = threading.Event()
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for signum in (signal.SIGINT, signal.SIGTERM):
            previous[signum] = signal.signal(signum, lambda *_: stop.set())
    try:
        run_gateway(args, address, capabilities, stop)
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    return 0


def run_gateway(
    args: argparse.Namespace,
    address: tuple[str, int],
    capabilities: GatewayCapabilities,
    stop: threading.Event,
) -> None:
    from robocloud.fleet.zenoh_session import open_client
    from robocloud.gateways.vda5050.gateway import Vda5050Gateway
    from robocloud.gateways.zenoh_side import RobotSide, ZenohFleet, ZenohRobots

    if not capabilities.capabilities:
        logging.getLogger(__name__).warning(
            "no --capabilities file: the AGVs are listed but have no capability, so none "
            "is chosen for a task"
        )
    session = open_client(
        args.connect, timeout=args.connect_timeout, security=security.from_arguments(args)
    )
    try:
        name = args.gateway_name

        def robot_side(on_command: CommandHandler) -> RobotSide:
            if name is None:
                return ZenohRobots(session, args.cloud, on_command)
            return ZenohFleet(session, args.cloud, name, on_command)

        gateway = Vda5050Gateway(
            robot_side,
            address[0],
            address[1],
            capabilities,
            interface=args.interface,
            major=args.major,
            timing=timing(args),
        )
        gateway.start(timeout=max(args.connect_timeout, 1.0))
        if args.metrics is not None:
            from robocloud.gateways.vda5050.metrics import serve_metrics

            serve_metrics(gateway, *args.metrics)
        print(
            f"VDA 5050 gateway: the AGVs of {args.mqtt} ({args.interface}/{args.major}) are "
            f"robots of {args.cloud} at {', '.join(args.connect)}; Ctrl-C stops",
            file=sys.stderr,
            flush=True,
        )
        try:
            stop.wait()
        finally:
            gateway.stop()
    finally:
        session.close()  # type: ignore[no-untyped-call]
