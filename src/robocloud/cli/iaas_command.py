"""``robocloud iaas``: one cloud's IaaS (HTTP API, Zenoh router, store) in one process.

Start-up goes in three steps, so that each mistake is one sentence (and its
exit code, see ``robocloud.cli.main``) before anything is left half open:

1. ``iaas_settings`` checks every argument and opens nothing: the cloud's
   name, the numbers, the API keys, the Zenoh endpoints' form, the security
   files, the store URL (a SQLite file's folder must exist; only ``var/``,
   the folder of the default store, is created).
2. The HTTP port is bound and the store opened, here rather than in the app's
   lifespan (``create_app`` takes the store), so a port in use or an
   unreachable database is said at once.
3. ``robocloud.cli.serving`` enters the app's lifespan (Zenoh router,
   overlay, request service) before uvicorn serves: an error while opening
   the router is one sentence, not uvicorn's log of a traceback.

SIGINT and SIGTERM stop the server; the lifespan and the store are then
closed in order and the command returns 0.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from robocloud.errors import InvalidInput
from robocloud.federation import security

if TYPE_CHECKING:
    from robocloud.iaas.config import Settings
    from robocloud.iaas.metrics import RouterRefusals

DEFAULT_ZENOH = "tcp/127.0.0.1:7447"


GC_YOUNG = 50_000  # allocations between two collections of the youngest generation
SWITCH_INTERVAL = 0.001  # seconds a thread may hold the GIL while another waits


def endpoint(text: str) -> tuple[str, int]:
    """``127.0.0.1:8101`` -> ("127.0.0.1", 8101); ``[::1]:8101`` for IPv6."""
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 < int(port) < 65536:
        raise argparse.ArgumentTypeError(f"{text!r} is not HOST:PORT")
    return host.strip("[]") or "127.0.0.1", int(port)


def add_iaas_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cloud", required=True, help="this provider's cloud name, e.g. cloud-a")
    parser.add_argument(
        "--listen",
        type=endpoint,
        default=("127.0.0.1", 8101),
        help="HTTP address (default 127.0.0.1:8101)",
    )
    parser.add_argument(
        "--zenoh",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help="Zenoh endpoint the robots connect to, repeatable (default tcp/127.0.0.1:7447)",
    )
    parser.add_argument(
        "--peer",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="another cloud's Zenoh endpoint to connect to, repeatable",
    )
    parser.add_argument(
        "--trust",
        action="append",
        default=[],
        metavar="CLOUD",
        help="a cloud whose commands for this cloud's robots are accepted, repeatable "
        "(default: every cloud on the overlay)",
    )
    parser.add_argument(
        "--store",
        default="",
        metavar="URL",
        help="sqlite:///FILE (default var/CLOUD.db) or postgresql+psycopg://...",
    )
    parser.add_argument(
        "--api-key",
        action="append",
        default=[],
        metavar="APP=KEY",
        help="an application and its API key, repeatable; also read from ROBOCLOUD_API_KEYS",
    )
    parser.add_argument("--optimizer", choices=("auto", "exact", "mopso"), default="auto")
    parser.add_argument(
        "--offline-after",
        type=float,
        default=5.0,
        metavar="SECONDS",
        help="a robot silent this long is offline (default 5)",
    )
    parser.add_argument(
        "--ack-timeout",
        type=float,
        default=2.0,
        metavar="SECONDS",
        help="how long a robot has to acknowledge a command; one that does not is told to "
        "stop at once (default 2)",
    )
    parser.add_argument(
        "--forget-after",
        type=float,
        default=600.0,
        metavar="SECONDS",
        help="a robot silent this long is forgotten, no longer listed (default 600)",
    )
    parser.add_argument(
        "--selection-budget",
        type=float,
        default=2.0,
        metavar="SECONDS",
        help="the time a selection may take; a cut search keeps the best coalitions found, "
        "and its worker process is stopped a second later (default 2)",
    )
    parser.add_argument(
        "--selection-workers",
        type=int,
        default=2,
        metavar="N",
        help="worker processes for selections, kept ready (up to twice as many when all "
        "are busy, but no more than the machine's cores); 0 runs them in a thread of the "
        "IaaS (default 2)",
    )
    parser.add_argument(
        "--busy-after",
        type=float,
        default=0.5,
        metavar="SECONDS",
        help="load shedding: new requests are refused (503, Retry-After) while 8 or more "
        "wait for their robots and the oldest has waited this long (default 0.5)",
    )
    parser.add_argument(
        "--max-waiting",
        type=int,
        default=1000,
        metavar="N",
        help="new requests are refused (503) while this many wait for their robots "
        "(default 1000)",
    )
    parser.add_argument(
        "--time-scale",
        type=float,
        default=1.0,
        metavar="X",
        help="robot time per wall second, as the simulator's --speedup",
    )
    parser.add_argument(
        "--overrun-ratio",
        type=float,
        default=0.5,
        metavar="R",
        help="the watchdog: a robot may run past its expected time (travel and work) by the "
        "larger of R times it and --overrun-min; then it is stopped and replaced (default 0.5)",
    )
    parser.add_argument(
        "--overrun-min",
        type=float,
        default=30.0,
        metavar="SECONDS",
        help="the watchdog's least tolerance, wall seconds (default 30)",
    )
    parser.add_argument(
        "--stall-after",
        type=float,
        default=30.0,
        metavar="SECONDS",
        help="a robot that reports no progress this long while it travels or works has "
        "stalled: stopped and replaced (default 30)",
    )
    parser.add_argument(
        "--set-aside-for",
        type=float,
        default=300.0,
        metavar="SECONDS",
        help="a robot that gives no ack, stalls or overruns twice in a row is not chosen for "
        "this long (default 300)",
    )
    parser.add_argument(
        "--lease-max",
        type=float,
        default=30.0,
        metavar="SECONDS",
        help="the longest lease on a robot lent to another cloud until its dispatch (default 30)",
    )
    parser.add_argument(
        "--lend-share",
        type=float,
        default=0.5,
        metavar="FRACTION",
        help="the most of this cloud's robots one other cloud may hold at once, 0 to 1 "
        "(default 0.5; docs/security.md)",
    )
    parser.add_argument(
        "--origin-deadline",
        type=float,
        default=60.0,
        metavar="SECONDS",
        help="how long a cloud this one lends to may stay unreachable once the robot is idle "
        "or done, before the loan ends (default 60)",
    )
    parser.add_argument(
        "--header-timeout",
        type=float,
        default=10.0,
        metavar="SECONDS",
        help="an HTTP connection whose request line and headers are not complete this long "
        "after it opened (or after the request's first byte) is closed (default 10)",
    )
    parser.add_argument(
        "--log-level", default="info", choices=("debug", "info", "warning", "error")
    )
    security.add_arguments(parser, router=True)


def iaas_command(args: argparse.Namespace) -> int:
    settings = iaas_settings(args)
    logging.basicConfig(
        level=args.log_level.upper(),
        format=f"%(asctime)s {settings.cloud} %(levelname)s %(name)s: %(message)s",
    )
    # Imported here: the other commands need none of the server's stack.
    from robocloud.cli.serving import listen_socket, serve
    from robocloud.iaas.app import create_app
    from robocloud.storage import open_store
    from robocloud.storage.opening import masked

    if not args.store:
        # The one folder robocloud makes: that of the store it chose itself.
        Path(settings.store_url.removeprefix("sqlite:///")).parent.mkdir(
            parents=True, exist_ok=True
        )
    with contextlib.ExitStack() as stack:
        listener = stack.enter_context(listen_socket(settings.host, settings.port, "--listen"))
        store = open_store(settings.store_url)
        stack.callback(store.close)
        ready = (
            f"serving http://{args.listen[0]}:{settings.port}/v1 (docs at /docs), "
            f"robots on {', '.join(settings.zenoh_listen)}, store {masked(settings.store_url)}"
        )
        app = create_app(settings, store=store, router_refusals=watch_router(settings))
        tune_runtime()
        serve(app, listener, args.log_level, settings.header_timeout, ready)
    return 0


def watch_router(settings: Settings) -> RouterRefusals | None:
    """With access control on the router, read what it refuses (log lines and a metric)."""
    security = settings.overlay_security
    if security is None or not security.identifies_peers:
        return None
    from robocloud.federation.security.router_refusals import watch

    entries = security.for_cloud(settings.cloud, settings.trusted).config_entries("router")
    return watch(settings.cloud, entries["access_control"]).counts


def tune_runtime() -> None:
    """Keep Python's collector and its GIL from slowing a server with a large fleet.

    50,000 robots at 1 Hz replace some 200,000 small objects a second (their
    states); with the default thresholds a full collection, over every object
    of the server, then ran about every second and took over half the CPU of
    reading the states. The objects made at start (the app, its schemas, the
    libraries) are frozen out of the collections, and the young generations
    are larger, so full collections are rarer and shorter (benchmarks/fleet.py).

    The thread reading the states is busy a third of the time then; the
    request threads get the GIL from it after 1 ms instead of Python's 5, which
    shortened POST-to-dispatched at 50,000 robots by about a third.
    """
    gc.collect()
    gc.freeze()
    gc.set_threshold(GC_YOUNG, 20, 20)
    sys.setswitchinterval(SWITCH_INTERVAL)


def iaas_settings(args: argparse.Namespace) -> Settings:
    """The IaaS's settings from its flags and environment, every one checked; nothing opened."""
    from robocloud.fleet.keys import check_chunk
    from robocloud.fleet.zenoh_session import check_endpoints
    from robocloud.iaas.config import Settings, default_store_url, parse_api_keys
    from robocloud.storage.opening import check_store_url

    check_chunk(args.cloud, "--cloud")
    if not 0 <= args.selection_workers <= 64:
        raise InvalidInput(
            f"--selection-workers must be 0 to 64, not {args.selection_workers}.",
            "--selection-workers",
        )
    for flag in (
        "--offline-after",
        "--ack-timeout",
        "--forget-after",
        "--time-scale",
        "--selection-budget",
        "--busy-after",
        "--overrun-min",
        "--stall-after",
        "--set-aside-for",
        "--header-timeout",
    ):
        value = getattr(args, flag.removeprefix("--").replace("-", "_"))
        if not value > 0:  # also refuses nan
            raise InvalidInput(f"{flag} must be more than 0, not {value}.", flag)
    if not 0 <= args.overrun_ratio <= 100:  # also refuses nan
        raise InvalidInput(
            f"--overrun-ratio must be 0 to 100, not {args.overrun_ratio}.", "--overrun-ratio"
        )
    if not 1 <= args.max_waiting <= 1_000_000:
        raise InvalidInput(
            f"--max-waiting must be 1 to 1000000, not {args.max_waiting}.", "--max-waiting"
        )
    if not 0 <= args.lend_share <= 1:  # also refuses nan
        raise InvalidInput(
            f"--lend-share must be 0 to 1 (a share of the robots), not {args.lend_share}.",
            "--lend-share",
        )
    for flag in ("--lease-max", "--origin-deadline"):
        value = getattr(args, flag.removeprefix("--").replace("-", "_"))
        if not 0 < value <= 86_400:
            raise InvalidInput(
                f"{flag} must be more than 0 and at most 86400 seconds, not {value}.", flag
            )
    zenoh_listen = tuple(args.zenoh or [DEFAULT_ZENOH])
    check_endpoints(zenoh_listen, "--zenoh")
    check_endpoints(args.peer, "--peer")
    for cloud in args.trust:
        check_chunk(cloud, "--trust")
    keys = parse_api_keys(",".join(args.api_key))
    overlay_security = security.from_arguments(args)  # the files exist and are PEM
    if args.store:
        check_store_url(args.store)
    settings = Settings.from_env(
        args.cloud,
        host=args.listen[0],
        port=args.listen[1],
        zenoh_listen=zenoh_listen,
        zenoh_peers=tuple(args.peer),
        trusted=tuple(args.trust),
        store_url=args.store or default_store_url(args.cloud),
        api_keys=keys,
        optimizer=args.optimizer,
        offline_after=args.offline_after,
        ack_timeout=args.ack_timeout,
        forget_after=args.forget_after,
        time_scale=args.time_scale,
        lease_max=args.lease_max,
        lend_share=args.lend_share,
        origin_deadline=args.origin_deadline,
        selection_budget=args.selection_budget,
        selection_workers=args.selection_workers,
        busy_after=args.busy_after,
        max_waiting=args.max_waiting,
        overrun_ratio=args.overrun_ratio,
        overrun_min=args.overrun_min,
        stall_after=args.stall_after,
        set_aside_for=args.set_aside_for,
        header_timeout=args.header_timeout,
        overlay_security=overlay_security,
    )
    return settings

