"""A stand-in ROS 2 robot with Nav2, speaking rmw_zenoh's or zenoh-bridge-ros2dds's keys.

For the tests and for anyone without a robot at hand::

    python -m robocloud.gateways.ros2.standin --listen tcp/127.0.0.1:7501 \\
        --scheme rmw_zenoh --distro jazzy [--namespace /bot1] [--domain 0] \\
        [--x 0 --y 0 --speed 1] [--battery 0.8] [--feedback-hz 20] [--tf-hz 30] \\
        [--log events.jsonl] [--count N]

Each robot is its own Zenoh router on its ``--listen`` endpoint (``--count``
more robots take the next ports, namespaces ``<namespace>_<i>``), as an
rmw_zenoh robot runs ``rmw_zenohd`` or a DDS robot runs the bridge. It
encodes with pycdr2 (``standin_cdr.py``), not with the gateway's codec.

What each robot does, and the knobs a test turns, are in ``standin_robot.py``.
"""

from __future__ import annotations

import argparse
import logging
import sys
import threading
import time

import zenoh

from robocloud.gateways.ros2 import interfaces as ros
from robocloud.gateways.ros2.standin_robot import StandinRobot
from robocloud.stopping import stop_on_signals

log = logging.getLogger("robocloud.ros2.standin")


def run(
    robots: list[StandinRobot], args: argparse.Namespace, stop: threading.Event
) -> dict[str, int]:
    """Publish on every robot at its rates until ``stop``; how many of each were sent."""
    sent = {"tf": 0, "feedback": 0, "battery": 0, "status": 0, "amcl": 0}
    tick = 0.5 / max(args.tf_hz, args.feedback_hz, 10.0)
    due = {"tf": 0.0, "feedback": 0.0, "battery": 0.0, "status": 0.0, "amcl": 0.0}
    every = {
        "tf": 1.0 / args.tf_hz,
        "feedback": 1.0 / args.feedback_hz,
        "battery": 1.0,
        "amcl": 0.5,
        "status": 1.0,
    }
    last = time.monotonic()
    while not stop.wait(tick):
        now = time.monotonic()
        dt, last = now - last, now
        for robot in robots:
            if robot.step(dt):
                robot.publish_status()
        for part, at in due.items():
            if now < at:
                continue
            # On schedule, not from now: a late tick does not lower the rate (nor do two
            # late ticks in a row make a burst: at most one period is caught up).
            due[part] = max(at + every[part], now - every[part])
            for robot in robots:
                try:
                    sent[part] += getattr(robot, f"publish_{part}")() is not False
                except zenoh.ZError:
                    log.exception("%s: publishing %s failed", robot.name, part)
    return sent


def parse(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m robocloud.gateways.ros2.standin",
                                description="A stand-in ROS 2 Nav2 robot on Zenoh.")  # fmt: skip
    p.add_argument("--listen", required=True, help="its router's endpoint, tcp/127.0.0.1:PORT")
    p.add_argument("--scheme", choices=("rmw_zenoh", "bridge"), default="rmw_zenoh")
    p.add_argument("--distro", choices=ros.DISTROS, default="jazzy")
    p.add_argument("--domain", type=int, default=0)
    p.add_argument("--namespace", default="")
    p.add_argument("--x", type=float, default=0.0)
    p.add_argument("--y", type=float, default=0.0)
    p.add_argument("--speed", type=float, default=1.0, help="m/s")
    p.add_argument("--battery", type=float, default=0.8, help="a fraction, 0 to 1, as ROS says it")
    p.add_argument("--feedback-hz", type=float, default=20.0)
    p.add_argument("--tf-hz", type=float, default=30.0)
    p.add_argument(
        "--no-map-tf",
        action="store_true",
        help="no map -> odom on /tf: the map pose only on /amcl_pose",
    )
    p.add_argument(
        "--old-attachment",
        action="store_true",
        help="send the pre-2025 attachment (requests are still checked for the new one)",
    )
    p.add_argument(
        "--result-timeout",
        type=float,
        default=0.0,
        metavar="SECONDS",
        help="end a held get_result without a reply after SECONDS, as a bridge "
        "does at its queries_timeout (default: never)",
    )
    p.add_argument("--log", help="JSONL file of what the robot was asked (the first robot's)")
    p.add_argument("--count", type=int, default=1, help="robots, on consecutive ports")
    args = p.parse_args(argv)
    if not (
        0 < args.speed <= 100
        and 0 <= args.battery <= 1
        and args.tf_hz > 0
        and args.feedback_hz > 0
        and 1 <= args.count <= 1000
    ):
        p.error("--speed 0 to 100, --battery 0 to 1, rates above 0, --count 1 to 1000")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    logging.basicConfig(level="INFO", format="%(asctime)s standin %(levelname)s: %(message)s")
    protocol, _, address = args.listen.partition("/")
    host, _, port = address.rpartition(":")
    robots = []
    for i in range(args.count):
        listen = f"{protocol}/{host}:{int(port) + i}"
        namespace = args.namespace if args.count == 1 else f"{args.namespace or '/bot'}_{i}"
        robots.append(StandinRobot(args, listen, namespace, i))
    try:
        with stop_on_signals() as stop:
            print(f"stand-in: {args.count} {args.scheme}/{args.distro} robot(s) at "
                  f"{args.listen}", file=sys.stderr, flush=True)  # fmt: skip
            started = time.monotonic()
            sent = run(robots, args, stop)
        took = time.monotonic() - started
        rates = ", ".join(f"{part} {n / took:.0f}/s" for part, n in sent.items())
        print(f"stand-in sent over {took:.1f} s: {rates}", file=sys.stderr, flush=True)
    finally:
        for robot in robots:
            robot.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
