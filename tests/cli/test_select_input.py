"""The columnar reader of ``robocloud select`` against the objects reader.

Same document, same answer: the same candidates with bit-identical t_i and
c_i and the same selection, or the same error sentence. The objects reader
(``parse_select_input``, one pydantic ``Robot`` per robot) is the reference.
"""

from __future__ import annotations

import copy
import io
import json
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import msgspec
import numpy as np
import pytest

from robocloud.cli import select_input
from robocloud.cli.main import main
from robocloud.cli.select_input import parse_select_input, read_candidates
from robocloud.domain.records import RobotRecord
from robocloud.errors import InvalidInput
from robocloud.selection.filtering import filter_robots
from robocloud.selection.pipeline import select
from robocloud.selection.problem import CoalitionProblem
from robocloud.sim.scenario import wildfire_scenario

Document = dict[str, Any]


@pytest.fixture(autouse=True)
def small_pieces(monkeypatch: pytest.MonkeyPatch) -> None:
    """Pieces of 7 robots, so every document here spans several."""
    monkeypatch.setattr(select_input, "CHUNK", 7)


def objects_answer(data: bytes) -> tuple[str, Any]:
    """The reference: ("error", sentence) or ("ok", (candidates, task, total))."""
    try:
        robots, task = parse_select_input(select_input.decode_text(data, "the input"))
    except InvalidInput as error:
        return "error", error.message
    return "ok", (filter_robots(robots, task), task, len(robots))


def columnar_answer(data: bytes) -> tuple[str, Any]:
    try:
        found = read_candidates(data)
    except InvalidInput as error:
        return "error", error.message
    return "ok", (found.robots, found.task, found.total)


def assert_same_answer(data: bytes) -> str:
    """Both readers agree; returns the error sentence, or "" when the document is valid."""
    expected, got = objects_answer(data), columnar_answer(data)
    assert got[0] == expected[0], (got, expected)
    if expected[0] == "error":
        assert got[1] == expected[1]
        return str(got[1])
    (old, old_task, old_total), (new, new_task, new_total) = expected[1], got[1]
    assert new_task == old_task
    assert new_total == old_total
    assert [r.id for r in new] == [r.id for r in old]
    old_problem = CoalitionProblem.build(old, old_task)
    new_problem = CoalitionProblem.build(new, new_task)
    assert new_problem.ids == old_problem.ids
    for name in ("time", "cost", "uses"):  # bit for bit, not within a tolerance
        assert getattr(new_problem, name).tobytes() == getattr(old_problem, name).tobytes()
    return ""


def encoded(document: Document) -> bytes:
    return json.dumps(document).encode()


# --- valid documents: the same selection --------------------------------------------


def select_both(document: Document, **options: Any) -> tuple[dict[str, Any], dict[str, Any]]:
    data = encoded(document)
    robots, task = parse_select_input(data.decode())
    found = read_candidates(data)
    assert found.reader == "columnar"
    old = select(robots, task, budget_s=None, **options)
    new = select(found.robots, found.task, budget_s=None, **options)
    assert new.pool == old.pool
    old_json, new_json = old.to_json(), new.to_json()
    old_json.pop("elapsed_ms")
    new_json.pop("elapsed_ms")
    return old_json, new_json


@pytest.mark.parametrize(
    ("robots", "clouds", "seed", "task_change", "options"),
    [
        (1000, 3, 0, {}, {"optimizer": "exact"}),
        (3000, 5, 1, {"priority": "cost", "execution": "sequential"}, {"optimizer": "exact"}),
        (2000, 2, 2, {"priority": "balanced", "min_battery": 40.0}, {"optimizer": "exact"}),
        (1500, 4, 3, {}, {"optimizer": "mopso", "seed": 5, "pool_size": 30}),
        (800, 1, 4, {"max_time": 60.0}, {"optimizer": "exact"}),  # nothing feasible
    ],
)
def test_same_selection_on_generated_scenarios(
    robots: int, clouds: int, seed: int, task_change: dict[str, Any], options: dict[str, Any]
) -> None:
    document = wildfire_scenario(robots, clouds, seed)
    document["task"].update(task_change)
    old, new = select_both(document, **options)
    assert new == old
    assert new["candidates"] > 0


def random_document(rng: np.random.Generator, n: int) -> Document:
    """Robots with ints and floats, negative coordinates, every status, odd capability sets."""
    names = ["light", "sound", "grabber", "kicker", "hose"]
    robots = []
    for i in range(n):
        caps = {}
        for name in rng.choice(names, size=int(rng.integers(0, 4)), replace=False).tolist():
            value = rng.uniform(0, 100)
            caps[name] = {
                "kind": "sensing" if name in ("light", "sound") else "actuating",
                "time": int(value) if rng.random() < 0.3 else float(value),
                "cost": float(rng.uniform(0, 10)) if rng.random() < 0.8 else 0,
            }
        robots.append({
            "id": f"r{i}",
            "cloud": f"c{i % 3}",
            "position": [float(rng.uniform(-500, 500)), int(rng.integers(-500, 500))],
            "speed": float(rng.uniform(0.001, 5)),
            "battery": float(rng.uniform(0, 100)) if rng.random() < 0.9 else 100,
            "status": str(rng.choice(["idle", "idle", "busy", "charging", "offline"])),
            "travel_cost_per_m": float(rng.exponential(0.05)),
            "capabilities": caps,
        })
    task = {
        "location": [1.5, -2.25],
        "sensing": {"light": 1},
        "actuating": {"grabber": 1, "kicker": 1},
        "max_robots": 6,
        "max_cost": 400.0,
        "max_time": 900.0,
        "min_battery": 30,
        "priority": "time",
    }
    return {"robots": robots, "task": task}


@pytest.mark.parametrize("seed", range(4))
def test_same_candidates_and_terms_on_random_documents(seed: int) -> None:
    rng = np.random.default_rng(seed)
    document = random_document(rng, int(rng.integers(1, 400)))
    assert assert_same_answer(encoded(document)) == ""
    old, new = select_both(document, optimizer="exact")
    assert new == old


# --- bad documents: the same sentence -----------------------------------------------

Change = Callable[[Document], object]


def robot(index: int, **fields: Any) -> Change:
    return lambda d: d["robots"][index].update(fields)


def drop(index: int, name: str) -> Change:
    return lambda d: d["robots"][index].pop(name)


def capability(index: int, name: str, value: Any) -> Change:
    return lambda d: d["robots"][index]["capabilities"].update({name: value})


def replace_robot(index: int, value: Any) -> Change:
    return lambda d: d["robots"].__setitem__(index, value)


def both(*changes: Change) -> Change:
    return lambda d: [change(d) for change in changes]


OK_CAP = {"kind": "sensing", "time": 1.0, "cost": 1.0}
MUTATIONS: list[tuple[str, Change]] = [
    ("unchanged", lambda d: None),
    ("no robots", lambda d: d.update(robots=[])),
    *[(f"missing {name}", drop(4, name)) for name in (
        "id", "cloud", "position", "speed", "battery", "status", "travel_cost_per_m",
        "capabilities")],
    ("extra field", robot(3, colour="red")),
    ("speed a string", robot(5, speed="fast")),
    ("speed true", robot(5, speed=True)),
    ("speed null", robot(5, speed=None)),
    ("speed an int", robot(5, speed=2)),
    ("speed at its least", robot(5, speed=0.001)),
    ("speed under its least", robot(5, speed=0.0009)),
    ("speed at its most", robot(5, speed=1000)),
    ("speed over its most", robot(5, speed=1000.5)),
    ("speed huge int", robot(5, speed=10**30)),
    ("battery full", robot(6, battery=100)),
    ("battery over full", robot(6, battery=100.01)),
    ("battery negative", robot(6, battery=-0.5)),
    ("battery minus zero", robot(6, battery=-0.0)),
    ("position of one", robot(2, position=[1.0])),
    ("position of three", robot(2, position=[1.0, 2.0, 3.0])),
    ("position an object", robot(2, position={"x": 1})),
    ("position a string", robot(2, position="1,2")),
    ("position at the edge", robot(2, position=[-1e7, 1e7])),
    ("position past the edge", robot(2, position=[-1e7 - 1, 0])),
    ("position a bool", robot(2, position=[True, 1.0])),
    ("status unknown", robot(0, status="asleep")),
    ("status an int", robot(0, status=1)),
    ("travel cost at its most", robot(1, travel_cost_per_m=1e9)),
    ("travel cost over", robot(1, travel_cost_per_m=1e9 + 1)),
    ("id empty", robot(1, id="")),
    ("id of 128", robot(1, id="x" * 128)),
    ("id of 129", robot(1, id="x" * 129)),
    ("id of 128 emoji", robot(1, id="\U0001f525" * 128)),
    ("id of 129 emoji", robot(1, id="\U0001f525" * 129)),
    ("id with a newline", robot(1, id="a\nb")),
    ("id ending in a newline", robot(1, id="ab\n")),
    ("id with a tab", robot(1, id="a\tb")),
    ("id with NUL", robot(1, id="a\u0000")),
    ("id with DEL", robot(1, id="a\u007f")),
    ("id with an escaped quote", robot(1, id='a"b')),
    ("id an int", robot(1, id=7)),
    ("cloud with a newline", robot(1, cloud="cloud\n")),
    ("capabilities a list", robot(1, capabilities=["light"])),
    ("capabilities empty", robot(1, capabilities={})),
    ("capability kind unknown", capability(1, "x", {"kind": "flying", "time": 1, "cost": 1})),
    ("capability missing cost", capability(1, "x", {"kind": "sensing", "time": 1})),
    ("capability extra", capability(1, "x", {**OK_CAP, "colour": "red"})),
    ("capability negative time", capability(1, "x", {**OK_CAP, "time": -1})),
    ("capability name empty", capability(1, "", OK_CAP)),
    ("capability name of 129", capability(1, "n" * 129, OK_CAP)),
    ("capability name with a newline", capability(1, "light\n", OK_CAP)),
    ("capability a number", capability(1, "x", 3)),
    ("robot a number", replace_robot(3, 5)),
    ("robot null", replace_robot(3, None)),
    ("robot a list", replace_robot(3, [])),
    ("two bad robots", both(robot(2, speed=-1.0), robot(9, battery=101))),
    ("a robot with two problems", both(robot(8, speed="x"), drop(8, "cloud"))),
    ("bad robot and bad task", both(robot(12, speed=0), lambda d: d["task"].pop("max_cost"))),
    ("bad task", lambda d: d["task"].update(priority="urgent")),
    ("bad task and a repeated id", both(
        lambda d: d["task"].update(max_robots=0), robot(7, id="a-0003"))),
    ("a repeated id", robot(7, id="a-0003")),
    ("two repeated ids", both(robot(7, id="a-0003"), robot(11, id="a-0001"))),
    ("an unknown top field", lambda d: d.update(extra=1)),
    ("robots missing", lambda d: d.pop("robots")),
    ("task missing", lambda d: d.pop("task")),
    ("robots an object", lambda d: d.update(robots={"a": 1})),
    ("task a list", lambda d: d.update(task=[])),
]


@pytest.fixture(scope="module")
def scenario() -> Document:
    return wildfire_scenario(40, 3, 0)


@pytest.mark.parametrize(("label", "change"), MUTATIONS, ids=[m[0] for m in MUTATIONS])
def test_same_answer_to_every_document(scenario: Document, label: str, change: Change) -> None:
    document = copy.deepcopy(scenario)
    change(document)
    assert_same_answer(encoded(document))
    # Written with every non-ASCII character escaped as well: the names' pattern is then
    # checked by msgspec (CheckedRobotRecord), not skipped.
    assert_same_answer(json.dumps(document, ensure_ascii=True, indent=1).encode())


def test_the_names_pattern_is_checked_when_the_document_may_hold_an_escape(
    scenario: Document,
) -> None:
    document = copy.deepcopy(scenario)
    document["robots"][20]["id"] = "tab\there"
    sentence = assert_same_answer(encoded(document))
    assert sentence == (
        "robots[20].id must be printable text on one line "
        "(no control character or bidirectional override)."
    )
    document["robots"][20]["id"] = "caf\u00e9"  # escaped by json.dumps, and valid
    assert assert_same_answer(encoded(document)) == ""


TEXTS: list[tuple[str, bytes]] = [
    ("empty", b""),
    ("not JSON", b"{not json"),
    ("NaN in a robot", b'{"robots": [{"id": "a", "speed": NaN}], "task": {}}'),
    ("NaN in the task", b'{"robots": [], "task": {"max_cost": NaN}}'),
    ("Infinity", b'{"robots": [], "task": {"max_cost": -Infinity}}'),
    ("a huge number", b'{"robots": [{"id": "a", "speed": 1e400}], "task": {}}'),
    ("an array", b"[1, 2]"),
    ("a string", b'"robots"'),
    ("trailing comma", b'{"robots": [], "task": {},}'),
    ("trailing text", b'{"robots": [], "task": {}} x'),
    ("BOM", b'\xef\xbb\xbf{"robots": [], "task": {}}'),
    ("not UTF-8", b'{"robots": [{"id": "\xff"}], "task": {}}'),
    ("lone surrogate", b'{"robots": [{"id": "\\ud800"}], "task": {}}'),
    ("CRLF and an error on line 3", b'{\r\n"robots": [],\r\n "task": {,}}'),
    ("duplicate key", b'{"robots": [], "robots": [], "task": {}}'),
]


@pytest.mark.parametrize(("label", "data"), TEXTS, ids=[t[0] for t in TEXTS])
def test_same_answer_to_every_text(label: str, data: bytes) -> None:
    try:
        expected = objects_answer(data)
    except InvalidInput as error:  # not UTF-8: the text decoding's own sentence
        expected = ("error", error.message)
    assert columnar_answer(data) == expected


def test_duplicate_keys_in_a_robot_take_the_last(scenario: Document) -> None:
    text = json.dumps(scenario)
    first = json.dumps(scenario["robots"][0])
    doubled = first.replace('"speed": ', '"speed": "fast", "speed": ', 1)
    assert doubled != first
    assert_same_answer(text.replace(first, doubled, 1).encode())


class Stricter(RobotRecord, frozen=True, gc=False):
    """Refuses speeds over 1 m/s, which ``Robot`` takes."""

    speed: Annotated[float, msgspec.Meta(ge=0.001, le=1.0)]


def test_a_disagreement_goes_to_the_objects_reader(
    scenario: Document, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A robot msgspec refuses and pydantic takes: the objects reader answers."""
    monkeypatch.setattr(select_input, "RobotRecord", Stricter)
    found = read_candidates(encoded(scenario))
    assert found.reader == "objects"
    robots, task = parse_select_input(json.dumps(scenario))
    assert [r.id for r in found.robots] == [r.id for r in filter_robots(robots, task)]
    assert found.total == len(robots) == 40


# --- the command ------------------------------------------------------------------


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def without_elapsed(out: str) -> dict[str, Any]:
    result: dict[str, Any] = json.loads(out)
    result.pop("elapsed_ms")
    return result


def test_command_readers_print_the_same(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    path = tmp_path / "fire.json"
    path.write_text(json.dumps(wildfire_scenario(2000, 3, 6)))
    code, columnar, err = run(capsys, "select", str(path))
    assert (code, err) == (0, "")
    code, objects, err = run(capsys, "select", str(path), "--reader", "objects")
    assert (code, err) == (0, "")
    assert without_elapsed(columnar) == without_elapsed(objects)


TIMINGS = re.compile(
    r"robocloud: timings \(ms\): reading [\d.]+, filtering [\d.]+, ranking [\d.]+, "
    r"optimisation [\d.]+, writing [\d.]+, total [\d.]+\n"
)


@pytest.mark.parametrize("reader", ["columnar", "objects"])
def test_command_timings(capsys: pytest.CaptureFixture[str], tmp_path: Path, reader: str) -> None:
    path = tmp_path / "fire.json"
    path.write_text(json.dumps(wildfire_scenario(300, 3, 1)))
    code, out, err = run(capsys, "select", str(path), "--timings", "--reader", reader)
    assert code == 0
    assert json.loads(out)["candidates"] == 30  # stdout: still one document
    assert TIMINGS.fullmatch(err), err


def test_command_bad_robot_in_a_large_file(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    document = wildfire_scenario(3000, 3, 2)
    document["robots"][2718]["capabilities"]["light"] = {"kind": "sensing", "time": -1, "cost": 0}
    path = tmp_path / "fire.json"
    path.write_text(json.dumps(document))
    code, out, err = run(capsys, "select", str(path))
    assert (code, out) == (2, "")
    assert err == (
        "robocloud: robots[2718].capabilities.light.time: "
        "input should be greater than or equal to 0.\n"
    )


def test_command_stdin_bytes(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    document = wildfire_scenario(200, 2, 3)
    stdin = io.TextIOWrapper(io.BytesIO(json.dumps(document).encode()), encoding="utf-8")
    monkeypatch.setattr(sys, "stdin", stdin)
    code, out, err = run(capsys, "select", "-")
    assert (code, err) == (0, "")
    assert json.loads(out)["candidates"] == 20


def test_command_stdin_not_utf8(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    stdin = io.TextIOWrapper(io.BytesIO(b'{"robots": ["\xff"], "task": {}}'), encoding="utf-8")
    monkeypatch.setattr(sys, "stdin", stdin)
    code, out, err = run(capsys, "select", "-")
    assert (code, out) == (2, "")
    assert err == "robocloud: stdin is not UTF-8 text (invalid start byte).\n"



@pytest.mark.parametrize("value", ["-1", "nan", "inf"])
def test_command_bad_budget(capsys: pytest.CaptureFixture[str], tmp_path: Path, value: str) -> None:
    path = tmp_path / "fire.json"
    path.write_text(json.dumps(wildfire_scenario(50, 3, 1)))
    code, out, err = run(capsys, "select", str(path), "--budget", value)
    assert (code, out) == (2, "")
    assert err == f"robocloud: --budget must be 0 (no limit) or more seconds, not {float(value)}.\n"


def test_command_budget(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    path = tmp_path / "fire.json"
    path.write_text(json.dumps(wildfire_scenario(1000, 3, 1)))
    answers = []
    for budget in ("0", "0.000001", "30"):
        code, out, err = run(capsys, "select", str(path), "--budget", budget)
        assert (code, err) == (0, "")
        answers.append(json.loads(out))
    unlimited, tiny, generous = answers
    assert unlimited["complete"] and generous["complete"]
    assert without_elapsed(json.dumps(unlimited)) == without_elapsed(json.dumps(generous))
    assert not tiny["complete"] and "time budget of 1e-06 s" in tiny["note"]
