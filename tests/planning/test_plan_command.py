"""``robocloud plan``: missions and MRTA-Benchmark instances in, valid plans out;
one sentence and exit code 2 for bad input."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import pytest
from mrta_dataset import visible

from robocloud.cli.main import main
from robocloud.planning.validate import TOLERANCE, check_mission, check_mrta


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def write(tmp_path: Path, document: Any, name: str = "input.json") -> str:
    path = tmp_path / name
    path.write_text(document if isinstance(document, str) else json.dumps(document))
    return str(path)


def one_sentence(err: str, *words: str) -> None:
    assert err.startswith("robocloud: ") and err.endswith(".\n") and err.count("\n") == 1
    assert "Traceback" not in err
    for word in words:
        assert word in err, err


def robot(name: str, x: float, capabilities: dict[str, tuple[float, float]], *,
          speed: float = 1.0, per_m: float = 0.0) -> dict[str, Any]:
    return {"id": name, "cloud": "cloud-a", "position": [x, 0.0], "speed": speed,
            "battery": 90.0, "status": "idle", "travel_cost_per_m": per_m,
            "capabilities": {c: {"kind": "actuating", "time": t, "cost": cost}
                             for c, (t, cost) in capabilities.items()}}


FIVE_FIRES: dict[str, Any] = {
    "robots": [
        robot("a-1", 0.0, {"water": (30.0, 5.0)}),
        robot("a-2", 10.0, {"water": (40.0, 5.0), "camera": (5.0, 1.0)}),
        robot("b-1", 50.0, {"grabber": (60.0, 8.0)}, speed=2.0),
        robot("b-2", 60.0, {"camera": (5.0, 1.0), "grabber": (50.0, 8.0)}),
        robot("b-3", 0.0, {"water": (35.0, 4.0)}, speed=0.5),
    ],
    "mission": {
        "tasks": [
            {"id": "fire-1", "location": [20.0, 10.0], "actuating": {"water": 2}},
            {"id": "fire-2", "location": [40.0, 30.0], "actuating": {"water": 1, "grabber": 1}},
            {"id": "fire-3", "location": [80.0, 10.0], "actuating": {"camera": 1},
             "duration": 20.0},
            {"id": "fire-4", "location": [60.0, 60.0], "actuating": {"grabber": 2}},
            {"id": "fire-5", "location": [10.0, 70.0], "actuating": {"water": 1, "camera": 1}},
        ],
        "precedence": [["fire-1", "fire-2"], ["fire-3", "fire-4"]],
        "end": [0.0, 0.0],
        "priority": "time",
    },
}


def test_an_instance_is_planned_in_the_datasets_format(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _name, instance, reference, optimum = visible()[1]
    code, out, err = run(capsys, "plan", write(tmp_path, instance), "--time-limit", "20")
    assert (code, err) == (0, "")
    output = json.loads(out)
    assert set(output) == set(reference) | {"lower_bound", "gap"}
    assert output["makespan"] == pytest.approx(optimum, abs=TOLERANCE)
    assert check_mrta(instance, output) == []
    assert output["lower_bound"] <= output["makespan"]


def test_a_mission_of_five_fires_is_planned_validly(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run(capsys, "plan", write(tmp_path, FIVE_FIRES), "--time-limit", "20")
    assert (code, err) == (0, "")
    plan = json.loads(out)
    assert check_mission(FIVE_FIRES, plan) == []
    assert plan["status"] == "optimal" and plan["method"] == "exact"
    assert plan["gap"] < 1e-4
    ends = {t["id"]: t["end"] for t in plan["tasks"]}
    starts = {t["id"]: t["start"] for t in plan["tasks"]}
    assert starts["fire-2"] >= ends["fire-1"] and starts["fire-4"] >= ends["fire-3"]


def test_cost_priority_trades_time_for_money(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # A fast dear robot and a slow cheap one, one task each way: time takes the fast one.
    document: dict[str, Any] = {
        "robots": [robot("fast", 0.0, {"water": (10.0, 100.0)}, speed=5.0),
                   robot("slow", 0.0, {"water": (10.0, 1.0)}, speed=1.0)],
        "mission": {"tasks": [{"id": "f", "location": [100.0, 0.0],
                               "actuating": {"water": 1}}]},
    }
    plans = {}
    for priority in ("time", "cost"):
        document["mission"]["priority"] = priority
        code, out, _ = run(capsys, "plan", write(tmp_path, document), "--time-limit", "20")
        assert code == 0
        plans[priority] = json.loads(out)
        assert check_mission(document, plans[priority]) == []
    assert plans["time"]["tasks"][0]["robots"] == ["fast"]
    assert plans["cost"]["tasks"][0]["robots"] == ["slow"]
    assert plans["cost"]["cost"] < plans["time"]["cost"]
    assert plans["time"]["makespan"] < plans["cost"]["makespan"]


def test_a_mission_nobody_can_do_says_why(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    document = copy.deepcopy(FIVE_FIRES)
    document["mission"]["tasks"][0]["actuating"] = {"water": 9}
    code, out, _ = run(capsys, "plan", write(tmp_path, document))
    plan = json.loads(out)
    assert code == 0 and plan["status"] == "infeasible" and plan["tasks"] == []
    assert "fire-1 needs 9 robots bringing 'water'" in plan["reason"]


def _mutated(change: str) -> Any:
    instance = copy.deepcopy(visible()[0][1])
    mission = copy.deepcopy(FIVE_FIRES)
    if change == "short T_t":
        instance["T_t"] = instance["T_t"][:-1]
        return instance
    if change == "skill flag":
        instance["Q"][1][2] = 2
        return instance
    if change == "precedence cycle":
        instance["precedence_constraints"] = [[1, 2], [2, 1]]
        return instance
    if change == "unknown task":
        mission["mission"]["precedence"] = [["fire-1", "fire-9"]]
        return mission
    if change == "negative speed":
        mission["robots"][0]["speed"] = -1
        return mission
    if change == "mission cycle":
        mission["mission"]["precedence"] = [["fire-1", "fire-2"], ["fire-2", "fire-1"]]
        return mission
    if change == "not an object":
        return [1, 2]
    return "{not json"


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ("short T_t", ("T_t must have 10 entries",)),
        ("skill flag", ("Q[1][2] must be 0 or 1",)),
        ("precedence cycle", ("precedence_constraints form a cycle",)),
        ("unknown task", ("mission.precedence", "fire-9")),
        ("negative speed", ("robots[0].speed",)),
        ("mission cycle", ("mission.precedence forms a cycle",)),
        ("not an object", ("must hold a JSON object",)),
        ("not JSON", ("is not valid JSON",)),
    ],
)
def test_bad_input_is_one_sentence_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], change: str, words: tuple[str, ...]
) -> None:
    document = _mutated(change)
    code, out, err = run(capsys, "plan", write(tmp_path, document))
    assert (code, out) == (2, "")
    one_sentence(err, *words)


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--time-limit", "0"], ("--time-limit must be more than 0",)),
        (["--time-limit", "nan"], ("--time-limit",)),
        (["--seed", "-1"], ("--seed must be at least 0",)),
    ],
)
def test_bad_options_are_one_sentence_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], words: tuple[str, ...]
) -> None:
    code, _, err = run(capsys, "plan", write(tmp_path, FIVE_FIRES), *argv)
    assert code == 2
    one_sentence(err, *words)


def test_a_missing_file_is_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "plan", str(tmp_path / "nothing.json"))
    assert code == 2
    one_sentence(err, "no such file")
