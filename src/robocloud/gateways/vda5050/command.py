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
import threading

from robocloud.errors import InvalidInput
from robocloud.gateways import command_common as common
from robocloud.gateways.vda5050.agv import Timing
from robocloud.gateways.vda5050.capabilities import GatewayCapabilities, load_capabilities
from robocloud.gateways.vda5050.messages import MAJOR
from robocloud.sim.metrics import metrics_address

DEFAULT_MQTT = "127.0.0.1:1883"


def add_vda5050_arguments(parser: argparse.ArgumentParser) -> None:
    common.add_common_arguments(parser, "the AGVs", "the router and the broker (default 10)")
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
        "--gateway-name",
        metavar="NAME",
        help="speak for the AGVs as a fleet gateway named NAME: a command queryable per "
        "AGV and their states on robocloud/<cloud>/fleets/NAME/states (default: the keys "
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
    common.check_common(args, args.gateway_name)
    address = mqtt_address(args.mqtt)
    topic_level(args.interface, "--interface")
    if args.major != MAJOR:
        raise InvalidInput(
            f"--major {args.major!r} is not spoken: the gateway speaks VDA 5050 2.x ({MAJOR}).",
            "--major",
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
    return common.run_until_stopped(
        args, "vda5050", lambda stop: run_gateway(args, address, capabilities, stop)
    )


def run_gateway(
    args: argparse.Namespace,
    address: tuple[str, int],
    capabilities: GatewayCapabilities,
    stop: threading.Event,
) -> None:
    from robocloud.gateways.vda5050.gateway import Vda5050Gateway

    if not capabilities.capabilities:
        logging.getLogger(__name__).warning(
            "no --capabilities file: the AGVs are listed but have no capability, so none "
            "is chosen for a task"
        )
    with common.zenoh_client(args) as session:
        gateway = Vda5050Gateway(
            common.robot_side(session, args.cloud, args.gateway_name),
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
        try:
            common.wait_until_stopped(
                stop,
                f"VDA 5050 gateway: the AGVs of {args.mqtt} ({args.interface}/{args.major}) "
                f"are robots of {args.cloud} at {', '.join(args.connect)}",
            )
        finally:
            gateway.stop()
