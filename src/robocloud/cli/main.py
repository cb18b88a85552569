"""The ``robocloud`` command.

::

    robocloud select SCENARIO.json [--optimizer auto|exact|mopso] [--seed N] [--pool-size K]
                     [--budget SECONDS] [--reader columnar|objects] [--timings]
    robocloud scenario wildfire [--robots 1000] [--clouds 3] [--seed N] [--output FILE]
    robocloud plan FILE [--time-limit S] [--seed N]    (robocloud.cli.plan_command)
    robocloud iaas --cloud NAME ...       (robocloud.cli.iaas_command)
    robocloud sim --cloud NAME ...        (robocloud.sim.command)
    robocloud wildfire --iaas URL ...     (robocloud.wildfire.command)
    robocloud robot-check --connect ENDPOINT --cloud NAME --robot ID   (robocloud.cli.robot_check)
    robocloud vda5050 --cloud NAME --connect ENDPOINT --mqtt HOST:PORT (robocloud.gateways.vda5050)
    robocloud nxt --cloud NAME --connect ENDPOINT --bricks FILE     (robocloud.gateways.nxt)
    robocloud nxt-brick --bricks FILE --robot ID                    (a stand-in NXT brick)
    robocloud ros2 --cloud NAME --connect ENDPOINT --robots FILE       (robocloud.gateways.ros2)

``select`` reads docs/model.md's input (a file, or ``-`` for stdin) and
prints its output as one JSON document on stdout; its columnar reader
(``robocloud.cli.select_input``) keeps a million robots within seconds and a
few hundred MB, ``--timings`` says where the time went. ``scenario wildfire``
writes the thesis's illustrative scenario (section 5.4) in that input shape.

Every command checks all its arguments before it opens anything (a file, a
port, a database, a Zenoh session). Exit codes, mapped in ``robocloud.cli.exits``
only:

- 0: done, also when no coalition is feasible (the output says why), and a
  server stopped by SIGINT or SIGTERM;
- 2: the user's input is wrong (:class:`~robocloud.errors.InvalidInput`,
  :class:`~robocloud.errors.NotFound`), and argparse's own usage errors;
- 1: anything else that stops a command: a store that cannot be reached, a
  port in use (other :class:`~robocloud.errors.RoboCloudError`), or an error
  nobody foresaw;
- 130: interrupted while starting.

Either way the user reads one sentence on stderr, never a traceback;
``--log-level debug`` (every command has it) prints the traceback before it.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from robocloud.cli.exits import (  # noqa: F401 (exit codes: re-exported)
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_INVALID,
    EXIT_OK,
    exit_code,
    run,
    say,
)
from robocloud.cli.iaas_command import add_iaas_arguments, iaas_command
from robocloud.cli.inputs import (  # noqa: F401 (STDIN, read_text: re-exported)
    STDIN,
    check_at_least,
    read_bytes,
    read_text,
    source_name,
)
from robocloud.cli.select_input import (  # noqa: F401 (parse_select_input: re-exported)
    check_unique_ids,
    parse_select_input,
)
from robocloud.errors import InvalidInput

if TYPE_CHECKING:
    from robocloud.domain import RobotLike




def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run(args.command, args, getattr(args, "command_name", "the command"))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="robocloud",
        description="Robot fleets of several providers federated into one robotic IaaS.",
    )
    commands = parser.add_subparsers(title="commands", metavar="COMMAND", required=True)

    select = commands.add_parser(
        "select",
        help="choose a coalition for a task (docs/model.md's select)",
        description="Read {robots, task} as JSON and print the selection as JSON.",
    )
    select.add_argument("scenario", metavar="SCENARIO.json", help="input file, or - for stdin")
    select.add_argument(
        "--optimizer",
        choices=("auto", "exact", "mopso"),
        default="auto",
        help="auto (default) takes the exact optimizer when the problem is small enough",
    )
    select.add_argument("--seed", type=int, default=0, help="seed of MOPSO (default 0)")
    select.add_argument(
        "--pool-size",
        type=int,
        default=None,
        metavar="K",
        help="how many of the best ranked candidates the optimizer searches",
    )
    select.add_argument(
        "--budget",
        type=float,
        default=None,
        metavar="SECONDS",
        help="time budget of the selection (default 2; 0: no limit, the same answer "
        "however loaded the machine)",
    )
    select.add_argument(
        "--reader",
        choices=("columnar", "objects"),
        default="columnar",
        help="columnar (default): msgspec, one light record per robot, filtered as read; "
        "objects: one pydantic Robot per robot (the former reader, for comparison)",
    )
    select.add_argument(
        "--timings",
        action="store_true",
        help="print on stderr where the time went: reading, filtering, ranking, "
        "optimisation, writing",
    )
    _add_log_level(select)
    select.set_defaults(command=select_command, command_name="select")

    scenario = commands.add_parser(
        "scenario",
        help="write a scenario as select's input",
        description="Write a generated scenario in select's input shape.",
    )
    scenario.add_argument("name", choices=("wildfire",), help="the thesis's section 5.4")
    scenario.add_argument("--robots", type=int, default=1000, help="fleet size (default 1000)")
    scenario.add_argument("--clouds", type=int, default=3, help="providers, 1 to 26 (default 3)")
    scenario.add_argument("--seed", type=int, default=0, help="default 0")
    scenario.add_argument("--output", metavar="FILE", help="write here instead of stdout")
    _add_log_level(scenario)
    scenario.set_defaults(command=scenario_command, command_name="scenario")

    from robocloud.cli.plan_command import add_plan_arguments, plan_command

    plan = commands.add_parser(
        "plan",
        help="plan a mission of several tasks (or an MRTA-Benchmark instance)",
        description="Read a mission or an MRTA-Benchmark instance and print its plan as JSON.",
    )
    add_plan_arguments(plan)
    _add_log_level(plan)
    plan.set_defaults(command=plan_command, command_name="plan")

    iaas = commands.add_parser(
        "iaas",
        help="run one cloud's IaaS: HTTP API, Zenoh router, store",
        description="Run one robot cloud's IaaS until interrupted.",
    )
    add_iaas_arguments(iaas)
    iaas.set_defaults(command=iaas_command, command_name="iaas")

    sim = commands.add_parser(
        "sim",
        help="simulate one cloud's robots, connected to its IaaS over Zenoh",
        description="Simulate N robots of one cloud until interrupted.",
    )
    from robocloud.sim.command import add_sim_arguments

    add_sim_arguments(sim)
    _add_log_level(sim)
    sim.set_defaults(command=_sim_command, command_name="sim")

    wildfire = commands.add_parser(
        "wildfire",
        help="serve the Wildfire Suppression Application for an IaaS",
        description="Serve the page and call the IaaS with the application's key.",
    )
    from robocloud.wildfire.command import add_wildfire_arguments

    add_wildfire_arguments(wildfire)
    wildfire.set_defaults(command=_wildfire_command, command_name="wildfire")

    from robocloud.cli.robot_check import add_robot_check_arguments, robot_check_command

    robot_check = commands.add_parser(
        "robot-check",
        help="check a robot against the robot protocol (a stand-in IaaS)",
        description="Drive one robot through every rule of docs/protocol.md; exit 0 if all pass.",
    )
    add_robot_check_arguments(robot_check)
    robot_check.set_defaults(command=robot_check_command, command_name="robot-check")

    from robocloud.gateways.vda5050.command import add_vda5050_arguments, vda5050_command

    gateway = commands.add_parser(
        "vda5050",
        help="make the AGVs of an MQTT broker (VDA 5050 2.x) robots of a cloud",
        description="Run the VDA 5050 gateway until interrupted.",
    )
    add_vda5050_arguments(gateway)
    gateway.set_defaults(command=vda5050_command, command_name="vda5050")

    from robocloud.gateways.nxt.command import add_nxt_arguments, nxt_command
    from robocloud.gateways.nxt.standin import add_standin_arguments, standin_command

    nxt = commands.add_parser(
        "nxt",
        help="make LEGO Mindstorms NXT bricks (Bluetooth direct commands) robots of a cloud",
        description="Run the NXT gateway until interrupted.",
    )
    add_nxt_arguments(nxt)
    nxt.set_defaults(command=nxt_command, command_name="nxt")
    nxt_brick = commands.add_parser(
        "nxt-brick",
        help="a stand-in NXT brick on a TCP socket, for tests and users without one",
        description="Play one brick of a bricks file: direct commands, simulated motors.",
    )
    add_standin_arguments(nxt_brick)
    nxt_brick.set_defaults(command=standin_command, command_name="nxt-brick")
    from robocloud.gateways.ros2.command import add_ros2_arguments, ros2_command

    ros2 = commands.add_parser(
        "ros2",
        help="make ROS 2 Nav2 robots (rmw_zenoh or zenoh-bridge-ros2dds) robots of a cloud",
        description="Run the ROS 2 gateway until interrupted.",
    )
    add_ros2_arguments(ros2)
    ros2.set_defaults(command=ros2_command, command_name="ros2")
    return parser


LOG_LEVELS = ("debug", "info", "warning", "error")


def _add_log_level(parser: argparse.ArgumentParser, default: str = "warning") -> None:
    """``--log-level`` for a command that does not define it itself."""
    with contextlib.suppress(argparse.ArgumentError):  # it does already
        parser.add_argument(
            "--log-level",
            default=default,
            choices=LOG_LEVELS,
            help=f"default {default}; debug also shows the traceback of an error",
        )


def _sim_command(args: argparse.Namespace) -> int:
    from robocloud.federation import security
    from robocloud.fleet.keys import check_chunk
    from robocloud.fleet.zenoh_session import check_endpoints
    from robocloud.sim.command import sim_command

    # Everything the simulator would refuse, before it connects to anything.
    check_chunk(args.cloud, "--cloud")
    check_at_least("--robots", args.robots, 1)
    check_at_least("--seed", args.seed, 0)
    if not args.speedup > 0:  # also refuses nan
        raise InvalidInput(f"--speedup must be more than 0, not {args.speedup}.", "--speedup")
    if not args.connect_timeout >= 0:  # 0: one try
        raise InvalidInput(
            f"--connect-timeout must be 0 or more, not {args.connect_timeout}.", "--connect-timeout"
        )
    check_endpoints(args.connect, "--connect")
    security.from_arguments(args)
    logging.basicConfig(
        level=args.log_level.upper(),
        format=f"%(asctime)s {args.cloud}-sim %(levelname)s %(name)s: %(message)s",
    )
    return sim_command(args)


def _wildfire_command(args: argparse.Namespace) -> int:
    from robocloud.cli.serving import listen_socket
    from robocloud.wildfire.command import wildfire_command

    if not args.timeout > 0:
        raise InvalidInput(f"--timeout must be more than 0, not {args.timeout}.", "--timeout")
    # A port in use is a sentence here rather than uvicorn's log after start-up;
    # the server binds it again right after (SO_REUSEADDR).
    host, port = args.listen
    with listen_socket(host, port, "--listen"):
        pass
    return wildfire_command(args)


# --- select ---------------------------------------------------------------


def select_command(args: argparse.Namespace) -> int:
    # Imported here: the selection stack is only needed by this command.
    from robocloud.cli.select_input import read_candidates
    from robocloud.selection.pipeline import DEFAULT_BUDGET_S, select

    started = time.perf_counter()
    check_at_least("--seed", args.seed, 0)
    if args.pool_size is not None:
        check_at_least("--pool-size", args.pool_size, 1)
    budget_s: float | None = DEFAULT_BUDGET_S
    if args.budget is not None:
        if not (args.budget >= 0 and math.isfinite(args.budget)):  # also refuses nan
            raise InvalidInput(
                f"--budget must be 0 (no limit) or more seconds, not {args.budget}.", "--budget"
            )
        budget_s = args.budget or None
    source = source_name(args.scenario)
    robots: Sequence[RobotLike]
    if args.reader == "objects":
        robots, task = parse_select_input(read_text(args.scenario), source)
        reading_ms, filtering_ms = (time.perf_counter() - started) * 1000.0, 0.0
    else:
        candidates = read_candidates(read_bytes(args.scenario), source)
        robots, task = candidates.robots, candidates.task
        reading_ms, filtering_ms = candidates.reading_ms, candidates.filtering_ms
        del candidates
    result = select(
        robots,
        task,
        optimizer=args.optimizer,
        seed=args.seed,
        pool_size=args.pool_size,
        budget_s=budget_s,
    )
    del robots
    before_writing = time.perf_counter()
    print(json.dumps(result.to_json()))
    if args.timings:
        sys.stdout.flush()
        stages = dict(result.stages)
        split = {
            "reading": reading_ms,
            "filtering": filtering_ms + stages.get("filtering", 0.0),
            "ranking": stages.get("ranking", 0.0),
            "optimisation": stages.get("optimisation", 0.0),
            "writing": (time.perf_counter() - before_writing) * 1000.0,
            "total": (time.perf_counter() - started) * 1000.0,
        }
        print(
            "robocloud: timings (ms): " + ", ".join(f"{k} {v:.1f}" for k, v in split.items()),
            file=sys.stderr,
        )
    return EXIT_OK


# --- scenario -------------------------------------------------------------


def scenario_command(args: argparse.Namespace) -> int:
    from robocloud.sim.scenario import MAX_CLOUDS, wildfire_scenario

    check_at_least("--robots", args.robots, 1)
    if not 1 <= args.clouds <= MAX_CLOUDS:
        raise InvalidInput(
            f"--clouds must be between 1 and {MAX_CLOUDS}, not {args.clouds}.", field="--clouds"
        )
    check_at_least("--seed", args.seed, 0)
    import msgspec

    # msgspec writes a million robots in about a second, json.dumps in ten.
    data = msgspec.json.encode(wildfire_scenario(args.robots, args.clouds, args.seed)) + b"\n"
    if args.output is None:
        buffer = getattr(sys.stdout, "buffer", None)  # none on a StringIO
        if buffer is None:
            sys.stdout.write(data.decode())
        else:
            sys.stdout.flush()
            buffer.write(data)
            buffer.flush()
        return EXIT_OK
    try:
        Path(args.output).write_bytes(data)
    except OSError as error:
        raise InvalidInput(
            f"cannot write {args.output}: {error.strerror or error}.", field="--output"
        ) from None
    return EXIT_OK


if __name__ == "__main__":
    raise SystemExit(main())
