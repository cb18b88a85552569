"""``robocloud plan FILE [--time-limit S] [--seed N]``: plan a mission, print it as JSON.

FILE (or ``-`` for stdin) holds either a mission (docs/model.md, "A mission":
``{"robots": [...], "mission": {...}}``) or an MRTA-Benchmark instance (told
apart by its fields ``Q``, ``R``, ``T_e``, ``T_t``). For an instance the
output is the dataset's own solution format (``makespan``, ``n_tasks``,
``n_robots``, ``robot_schedules``) with ``lower_bound`` and ``gap`` added,
so it compares one to one with the dataset's optimal schedules.
"""

from __future__ import annotations

import argparse
import json
import math
from typing import Any

from pydantic import ValidationError

from robocloud.cli.exits import EXIT_OK
from robocloud.cli.inputs import check_at_least, read_text, source_name
from robocloud.errors import InvalidInput, describe_validation_errors


def add_plan_arguments(parser: argparse.ArgumentParser) -> None:
    from robocloud.planning.solve import DEFAULT_TIME_LIMIT

    parser.add_argument("file", metavar="FILE", help="a mission or an MRTA-Benchmark instance "
                        "(JSON), or - for stdin")
    parser.add_argument(
        "--time-limit", type=float, default=DEFAULT_TIME_LIMIT, metavar="S",
        help=f"seconds the planner may take (default {DEFAULT_TIME_LIMIT:g})",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the search (default 0)")


def plan_command(args: argparse.Namespace) -> int:

    if not (math.isfinite(args.time_limit) and args.time_limit > 0):
        raise InvalidInput(
            f"--time-limit must be more than 0 seconds, not {args.time_limit}.", "--time-limit"
        )
    check_at_least("--seed", args.seed, 0)
    source = source_name(args.file)
    text = read_text(args.file)
    try:
        document = json.loads(text)
    except json.JSONDecodeError as error:
        raise InvalidInput(f"{source} is not valid JSON ({error.msg} at line {error.lineno}).",
                           "input") from None
    print(json.dumps(plan_input(document, text, args.time_limit, args.seed, source)))
    return EXIT_OK


def plan_input(
    document: object, text: str, time_limit: float, seed: int, source: str = "input"
) -> dict[str, Any]:
    """The plan of a mission or an instance, as ``robocloud plan`` prints it."""
    from robocloud.planning import mission as missions
    from robocloud.planning import mrta
    from robocloud.planning.solve import solve

    if mrta.is_instance(document):
        assert isinstance(document, dict)
        problem = mrta.read_instance(document)
        plan = solve(problem, time_limit, seed)
        assert plan.schedule is not None  # every skill is held: always a plan
        output = mrta.solution(problem, plan.schedule)
        output["lower_bound"] = plan.lower_bound
        output["gap"] = plan.gap
        return output
    if not isinstance(document, dict):
        raise InvalidInput(
            f"{source} must hold a JSON object: a mission ({{\"robots\": ..., \"mission\": ...}}) "
            "or an MRTA-Benchmark instance.", "input"
        )
    try:
        parsed = missions.MissionInput.model_validate_json(text)
    except ValidationError as error:
        raise describe_validation_errors(error.errors()) from None
    problem = missions.to_problem(parsed)
    return missions.plan_document(problem, solve(problem, time_limit, seed))
