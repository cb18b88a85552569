"""What the gateway commands share: their common arguments, checks and run.

``robocloud vda5050``, ``robocloud nxt`` and ``robocloud ros2`` each join one
cloud's router as a Zenoh client, speak for their robots on the keys of a
robot each or as a fleet gateway (``zenoh_side``), and run until SIGINT or
SIGTERM. Each one's own arguments, checks and gateway stay in its
``command.py``; this module is below all three and imports none of them.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
import threading
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

from robocloud.errors import InvalidInput
from robocloud.federation import security
from robocloud.stopping import stop_on_signals

if TYPE_CHECKING:
    import zenoh

    from robocloud.gateways.zenoh_side import CommandHandler, RobotSide

MAX_CONNECT_TIMEOUT = 3600.0  # seconds


def add_common_arguments(
    parser: argparse.ArgumentParser,
    robots: str,
    waits_for: str = "the cloud's router (default 10)",
) -> None:
    """``--cloud``, ``--connect``, ``--connect-timeout``, ``--log-level`` and the
    security flags of a client; ``robots`` names what joins, e.g. "the AGVs",
    and ``waits_for`` what the timeout bounds."""
    parser.add_argument("--cloud", required=True, help=f"the cloud {robots} join, e.g. cloud-a")
    parser.add_argument(
        "--connect",
        required=True,
        action="append",
        metavar="ZENOH_ENDPOINT",
        help="the IaaS's Zenoh router, e.g. tcp/127.0.0.1:7447 (repeat for fallbacks)",
    )
    parser.add_argument(
        "--connect-timeout",
        type=float,
        default=10.0,
        metavar="SECONDS",
        help=f"how long to wait for {waits_for}",
    )
    parser.add_argument(
        "--log-level",
        default="info",
        choices=("debug", "info", "warning", "error"),
        help="default info; debug also shows the traceback of an error",
    )
    security.add_arguments(parser, router=False)


def check_common(args: argparse.Namespace, gateway_name: str | None) -> None:
    """What every gateway refuses before it opens anything: the cloud's and the
    gateway's names, the endpoints, the timeout, the security flags."""
    from robocloud.fleet.keys import check_chunk
    from robocloud.fleet.zenoh_session import check_endpoints

    check_chunk(args.cloud, "--cloud")
    if gateway_name is not None:
        check_chunk(gateway_name, "--gateway-name")
    check_endpoints(args.connect, "--connect")
    if not 0 <= args.connect_timeout <= MAX_CONNECT_TIMEOUT:  # also refuses nan
        raise InvalidInput(
            f"--connect-timeout must be 0 to {MAX_CONNECT_TIMEOUT:g} s, "
            f"not {args.connect_timeout}.",
            "--connect-timeout",
        )
    security.from_arguments(args)


def run_until_stopped(
    args: argparse.Namespace, kind: str, run: Callable[[threading.Event], None]
) -> int:
    """Log as ``<cloud>-<kind>``, then ``run(stop)``: ``stop`` is set by SIGINT or
    SIGTERM (when on the main thread); 0 once ``run`` returned cleanly."""
    logging.basicConfig(
        level=args.log_level.upper(),
        format=f"%(asctime)s {args.cloud}-{kind} %(levelname)s %(name)s: %(message)s",
    )
    with stop_on_signals() as stop:
        run(stop)
    return 0


def wait_until_stopped(stop: threading.Event, banner: str) -> None:
    """Say what runs (one line on stderr, ending "Ctrl-C stops"), then wait for ``stop``."""
    print(f"{banner}; Ctrl-C stops", file=sys.stderr, flush=True)
    stop.wait()


@contextlib.contextmanager
def zenoh_client(args: argparse.Namespace) -> Iterator[zenoh.Session]:
    """The gateway's Zenoh client session to ``--connect``, closed at the end."""
    from robocloud.fleet.zenoh_session import open_client

    session = open_client(
        args.connect, timeout=args.connect_timeout, security=security.from_arguments(args)
    )
    try:
        yield session
    finally:
        session.close()  # type: ignore[no-untyped-call]


def robot_side(
    session: zenoh.Session, cloud: str, gateway_name: str | None
) -> Callable[[CommandHandler], RobotSide]:
    """How a gateway speaks: as a fleet gateway named ``gateway_name``, or (None)
    on the keys of a robot for each of its robots."""
    from robocloud.gateways.zenoh_side import ZenohFleet, ZenohRobots

    def side(on_command: CommandHandler) -> RobotSide:
        if gateway_name is None:
            return ZenohRobots(session, cloud, on_command)
        return ZenohFleet(session, cloud, gateway_name, on_command)

    return side
