"""``robocloud sim``: a simulated fleet of one cloud, connected to its IaaS.

::

    robocloud sim --cloud cloud-a --robots 100 --connect tcp/127.0.0.1:7447 --speedup 10
    python -m robocloud.sim.command --cloud cloud-a ...   (the same, without the CLI)

It runs until interrupted (Ctrl-C or SIGTERM).
"""

from __future__ import annotations

import argparse
import logging
import sys
import threading
from collections.abc import Sequence

from robocloud.cli.exits import run
from robocloud.errors import InvalidInput
from robocloud.federation import security
from robocloud.fleet import keys
from robocloud.sim.fleet import run_simulator
from robocloud.sim.metrics import metrics_address
from robocloud.stopping import stop_on_signals


def add_sim_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cloud", required=True, help="the cloud's name, e.g. cloud-a")
    parser.add_argument(
        "--robots", type=int, default=20, metavar="N", help="how many robots (default 20)"
    )
    parser.add_argument(
        "--connect",
        required=True,
        action="append",
        metavar="ENDPOINT",
        help="the IaaS's Zenoh router, e.g. tcp/127.0.0.1:7447 (repeat for fallbacks)",
    )
    parser.add_argument("--seed", type=int, default=0, help="draws the fleet (default 0)")
    parser.add_argument(
        "--speedup",
        type=float,
        default=1.0,
        metavar="X",
        help="simulated time runs X times faster than the clock (default 1)",
    )
    parser.add_argument(
        "--no-churn",
        dest="churn",
        action="store_false",
        help="robots change only by commands and faults, never on their own",
    )
    parser.add_argument(
        "--recharge-below",
        type=float,
        metavar="PERCENT",
        help="with --no-churn: an idle robot whose battery is below PERCENT charges until "
        "full, as a robot that docks itself would (default: never)",
    )
    parser.add_argument(
        "--connect-timeout",
        type=float,
        default=10.0,
        metavar="SECONDS",
        help="how long to wait for the router (default 10)",
    )
    parser.add_argument(
        "--gateway",
        metavar="NAME",
        help="act as a fleet gateway named NAME: publish the robots' states in batches on "
        "robocloud/<cloud>/fleets/NAME/states instead of a key per robot (for large fleets)",
    )
    parser.add_argument(
        "--metrics",
        type=metrics_address,
        metavar="HOST:PORT",
        help="serve Prometheus metrics at http://HOST:PORT/metrics (docs/metrics.md)",
    )
    security.add_arguments(parser, router=False)


def sim_command(args: argparse.Namespace) -> int:
    """Run the simulator until SIGINT or SIGTERM; 0 when it stopped cleanly.

    Errors a user can cause are raised as ``RoboCloudError`` for the CLI to map.
    """
    with stop_on_signals() as stop:
        return _run(args, stop)


def _run(args: argparse.Namespace, stop: threading.Event) -> int:
    overlay_security = security.from_arguments(args)  # bad flags: an error before anything runs
    if args.gateway is not None:
        keys.check_chunk(args.gateway, "gateway")
    if args.recharge_below is not None and not 0.0 < args.recharge_below <= 100.0:
        raise InvalidInput(
            f"--recharge-below must be a battery percentage above 0 and at most 100, "
            f"not {args.recharge_below:g}.",
            field="--recharge-below",
        )
    print(
        f"simulating {args.robots} robots of {args.cloud} at speedup {args.speedup:g},"
        f" connecting to {', '.join(args.connect)}; Ctrl-C stops",
        file=sys.stderr,
        flush=True,
    )
    run_simulator(
        args.cloud,
        args.robots,
        args.connect,
        seed=args.seed,
        speedup=args.speedup,
        stop_event=stop,
        churn=args.churn,
        connect_timeout=args.connect_timeout,
        security=overlay_security,
        gateway=args.gateway,
        metrics=args.metrics,
        recharge_below=args.recharge_below,
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="robocloud sim", description="A simulated fleet of one cloud."
    )
    add_sim_arguments(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    return run(sim_command, args, "robocloud sim")


if __name__ == "__main__":
    sys.exit(main())
