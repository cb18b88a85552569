"""``robocloud iaas``: one cloud's IaaS (HTTP API, Zenoh router, store) in one process."""

from __future__ import annotations

import argparse
import logging

from robocloud.errors import InvalidInput
from robocloud.federation import security


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
        "--time-scale",
        type=float,
        default=1.0,
        metavar="X",
        help="robot time per wall second, as the simulator's --speedup",
    )
    parser.add_argument(
        "--lease-max",
        type=float,
        default=30.0,
        metavar="SECONDS",
        help="the longest lease on a robot lent to another cloud until its dispatch (default 30)",
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
        "--log-level", default="info", choices=("debug", "info", "warning", "error")
    )
    security.add_arguments(parser, router=True)


def iaas_command(args: argparse.Namespace) -> int:
    import uvicorn

    from robocloud.iaas.app import create_app
    from robocloud.iaas.config import Settings, parse_api_keys

    if args.offline_after <= 0 or args.time_scale <= 0:
        raise InvalidInput("--offline-after and --time-scale must be positive.")
    if not 0 < args.lease_max <= 86_400 or not 0 < args.origin_deadline <= 86_400:
        raise InvalidInput(
            "--lease-max and --origin-deadline must be more than 0 and at most 86400 seconds."
        )
    keys = parse_api_keys(",".join(args.api_key))
    settings = Settings.from_env(
        args.cloud,
        host=args.listen[0],
        port=args.listen[1],
        zenoh_listen=tuple(args.zenoh or ["tcp/127.0.0.1:7447"]),
        zenoh_peers=tuple(args.peer),
        trusted=tuple(args.trust),
        store_url=args.store,
        api_keys=keys,
        optimizer=args.optimizer,
        offline_after=args.offline_after,
        time_scale=args.time_scale,
        lease_max=args.lease_max,
        origin_deadline=args.origin_deadline,
        overlay_security=security.from_arguments(args),
    )
    if settings.store_url.startswith("sqlite:///"):
        from pathlib import Path

        Path(settings.store_url.removeprefix("sqlite:///")).parent.mkdir(
            parents=True, exist_ok=True
        )
    logging.basicConfig(
        level=args.log_level.upper(),
        format=f"%(asctime)s {settings.cloud} %(levelname)s %(name)s: %(message)s",
    )
    app = create_app(settings)
    config = uvicorn.Config(
        app, host=settings.host, port=settings.port, log_level=args.log_level, access_log=False
    )
    uvicorn.Server(config).run()
    return 0
