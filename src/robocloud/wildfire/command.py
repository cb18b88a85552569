"""``robocloud wildfire``: the Wildfire Suppression Application's server.

::

    robocloud wildfire --iaas http://127.0.0.1:8101 [--iaas URL ...] [--api-key KEY]
                       [--listen 127.0.0.1:8000] [--forest 0,0,2000,2000] [--currency credits]
                       [--timeout 10] [--tick 1] [--silent-after 5]
    python -m robocloud.wildfire.command --iaas ...   (the same, without the CLI)

``--iaas`` may be repeated (the IaaSs of one federation, in order of
preference): the page keeps working while any one answers. The key may also
come from ``ROBOCLOUD_WILDFIRE_API_KEY``, which keeps it out of the process
list. The server runs until interrupted.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import sys
from collections.abc import Mapping, Sequence
from urllib.parse import urlsplit

from robocloud.cli.exits import run
from robocloud.errors import InvalidInput
from robocloud.wildfire.config import MAX_CURRENCY_CHARS, Forest, WildfireSettings

API_KEY_ENV = "ROBOCLOUD_WILDFIRE_API_KEY"
DEFAULT_LISTEN = ("127.0.0.1", 8000)


def listen_address(text: str) -> tuple[str, int]:
    """``127.0.0.1:8000`` -> ("127.0.0.1", 8000); ``[::1]:8000`` for IPv6."""
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 < int(port) < 65536:
        raise argparse.ArgumentTypeError(f"{text!r} is not HOST:PORT")
    return host.strip("[]") or "127.0.0.1", int(port)


def iaas_url(text: str) -> str:
    parts = urlsplit(text)
    if parts.scheme not in ("http", "https") or not parts.netloc:
        raise argparse.ArgumentTypeError(f"{text!r} is not an http:// or https:// URL")
    return text.rstrip("/")


def forest_area(text: str) -> Forest:
    try:
        return Forest.parse(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def currency_label(text: str) -> str:
    label = text.strip()
    if not label or len(label) > MAX_CURRENCY_CHARS or not label.isprintable():
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a label of 1 to {MAX_CURRENCY_CHARS} printable characters")
    return label


def add_wildfire_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--iaas",
        required=True,
        action="append",
        type=iaas_url,
        metavar="URL",
        help="an IaaS's HTTP API, e.g. http://127.0.0.1:8101; repeat it for the other clouds "
        "of the federation (requests go to the first that answers)",
    )
    parser.add_argument(
        "--api-key",
        default=None,
        metavar="KEY",
        help=f"the application's key at the IaaS (default: ${API_KEY_ENV})",
    )
    parser.add_argument(
        "--listen",
        type=listen_address,
        default=DEFAULT_LISTEN,
        metavar="HOST:PORT",
        help="where to serve the page (default 127.0.0.1:8000)",
    )
    parser.add_argument(
        "--timeout",
        type=float,
        default=10.0,
        metavar="SECONDS",
        help="how long to wait for the IaaS on the operator's behalf (default 10)",
    )
    parser.add_argument(
        "--tick",
        type=float,
        default=1.0,
        metavar="SECONDS",
        help="how often the IaaSs are read and each page is sent what changed (default 1)",
    )
    parser.add_argument(
        "--silent-after",
        type=float,
        default=5.0,
        metavar="SECONDS",
        help="a page that hears nothing from this server for this long greys what it shows "
        "and says so (default 5)",
    )
    parser.add_argument(
        "--forest",
        type=forest_area,
        default=Forest.parse("0,0,2000,2000"),
        metavar="X0,Y0,X1,Y1",
        help="the forest the application protects, in metres; a fire outside it is refused "
        "(default 0,0,2000,2000, the simulator's forest)",
    )
    parser.add_argument(
        "--currency",
        type=currency_label,
        default="credits",
        metavar="LABEL",
        help="the unit costs are shown in (default credits)",
    )
    parser.add_argument(
        "--log-level", default="info", choices=("debug", "info", "warning", "error")
    )


class _AtDebug(logging.Filter):
    """httpx logs each call at INFO; here it is a DEBUG line."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno == logging.INFO:
            record.levelno, record.levelname = logging.DEBUG, "DEBUG"
        return True


def quiet_iaas_calls(debug: bool) -> None:
    """Each call to an IaaS (httpx's "HTTP Request: ..." line) only at DEBUG.

    The page polls every tick: at INFO those lines were nearly the whole log
    (issue 26: 444 KB in 8 minutes). INFO says what happened to requests and
    clouds instead (``robocloud.wildfire.live``).
    """
    calls = logging.getLogger("httpx")
    calls.setLevel(logging.DEBUG if debug else logging.WARNING)
    if not any(isinstance(f, _AtDebug) for f in calls.filters):
        calls.addFilter(_AtDebug())


def page_url(host: str, port: int) -> str:
    shown = f"[{host}]" if ":" in host else host
    return f"http://{shown}:{port}/"


def wildfire_command(args: argparse.Namespace, environ: Mapping[str, str] | None = None) -> int:
    """Serve the page until interrupted; user errors are raised as ``RoboCloudError``."""
    import uvicorn

    from robocloud.wildfire.app import create_wildfire_app

    if not (math.isfinite(args.timeout) and args.timeout > 0):
        raise InvalidInput("--timeout must be positive.", "--timeout")
    for flag, value in (("--tick", args.tick), ("--silent-after", args.silent_after)):
        if not (math.isfinite(value) and value > 0):
            raise InvalidInput(f"{flag} must be positive.", flag)
    env = os.environ if environ is None else environ
    api_key = args.api_key or env.get(API_KEY_ENV) or None
    host, port = args.listen
    logging.basicConfig(
        level=args.log_level.upper(),
        format="%(asctime)s wildfire %(levelname)s %(name)s: %(message)s",
    )
    quiet_iaas_calls(args.log_level == "debug")
    if len(set(args.iaas)) != len(args.iaas):
        raise InvalidInput("an --iaas URL is given twice.", "--iaas")
    if api_key is None:
        # Every call to the IaaS would be refused (401) while the page looked fine.
        raise InvalidInput(
            f"no API key for the IaaS: set {API_KEY_ENV} (or pass --api-key) to a key "
            "the IaaS accepts.",
            "--api-key",
        )
    settings = WildfireSettings(
        iaas=tuple(args.iaas),
        api_key=api_key,
        forest=args.forest,
        currency=args.currency,
        timeout=args.timeout,
        poll_timeout=min(3.0, args.timeout),
        tick=args.tick,
        silent_after=args.silent_after,
    )
    app = create_wildfire_app(settings)
    config = uvicorn.Config(app, host=host, port=port, log_level=args.log_level, access_log=False)
    server = uvicorn.Server(config)
    print(
        f"wildfire: serving {page_url(host, port)} for the IaaS at {', '.join(args.iaas)}"
        "; Ctrl-C stops",
        file=sys.stderr,
        flush=True,
    )
    server.run()
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="robocloud wildfire",
        description="Serve the Wildfire Suppression Application for one or more IaaSs.",
    )
    add_wildfire_arguments(parser)
    args = parser.parse_args(argv)
    return run(wildfire_command, args, "robocloud wildfire")


if __name__ == "__main__":
    sys.exit(main())
