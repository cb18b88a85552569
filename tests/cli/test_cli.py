"""The ``robocloud`` command: select, scenario, and one sentence for every bad input."""

import copy
import io
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

import robocloud
from robocloud.cli.main import main
from robocloud.sim.scenario import wildfire_scenario

OUTPUT_KEYS = {"candidates", "ranking", "pareto", "chosen", "reason", "optimizer", "elapsed_ms",
               "complete", "bound", "note"}


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def write(tmp_path: Path, document: Any, name: str = "scenario.json") -> str:
    path = tmp_path / name
    path.write_text(document if isinstance(document, str) else json.dumps(document))
    return str(path)


def assert_one_sentence(err: str, *words: str) -> None:
    assert err.startswith("robocloud: ")
    assert err.endswith(".\n")
    assert err.count("\n") == 1
    assert "Traceback" not in err
    for word in words:
        assert word in err


@pytest.fixture(scope="module")
def small_scenario() -> dict[str, Any]:
    return wildfire_scenario(40, 3, 0)


# --- scenario ---------------------------------------------------------------


def test_scenario_to_stdout(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(
        capsys, "scenario", "wildfire", "--robots", "30", "--clouds", "2", "--seed", "4"
    )
    assert code == 0 and err == ""
    assert json.loads(out) == wildfire_scenario(30, 2, 4)


def test_scenario_defaults_to_the_thesis_size(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "scenario", "wildfire")
    assert code == 0
    data = json.loads(out)
    assert len(data["robots"]) == 1000
    assert {r["cloud"] for r in data["robots"]} == {"cloud-a", "cloud-b", "cloud-c"}


def test_scenario_to_a_file(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    target = tmp_path / "fire.json"
    code, out, err = run(capsys, "scenario", "wildfire", "--robots", "12", "--output", str(target))
    assert (code, out, err) == (0, "", "")
    assert json.loads(target.read_text()) == wildfire_scenario(12, 3, 0)


@pytest.mark.parametrize(
    ("argv", "field"),
    [
        (["--robots", "0"], "--robots"),
        (["--robots", "-3"], "--robots"),
        (["--clouds", "0"], "--clouds"),
        (["--clouds", "27"], "--clouds"),
        (["--seed", "-1"], "--seed"),
    ],
)
def test_scenario_bad_options(
    capsys: pytest.CaptureFixture[str], argv: list[str], field: str
) -> None:
    code, out, err = run(capsys, "scenario", "wildfire", *argv)
    assert code == 2 and out == ""
    assert_one_sentence(err, field)


def test_scenario_unwritable_output(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code, _, err = run(
        capsys,
        "scenario",
        "wildfire",
        "--robots",
        "3",
        "--output",
        str(tmp_path / "no" / "such" / "dir.json"),
    )
    assert code == 2
    assert_one_sentence(err, "cannot write")


def test_usage_errors_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    for argv in (["scenario", "flood"], ["select", "x.json", "--optimizer", "nsga"], []):
        with pytest.raises(SystemExit) as caught:
            main(argv)
        assert caught.value.code == 2
        assert "Traceback" not in capsys.readouterr().err


# --- select: bad input --------------------------------------------------------


def test_select_no_such_file(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    missing = str(tmp_path / "missing.json")
    code, out, err = run(capsys, "select", missing)
    assert code == 2 and out == ""
    assert_one_sentence(err, missing, "no such file")


def test_select_a_directory(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code, _, err = run(capsys, "select", str(tmp_path))
    assert code == 2
    assert_one_sentence(err, "cannot read")


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("{not json", ["not valid JSON", "line 1"]),
        ("", ["not valid JSON"]),
        ('{"robots": [], "task": {"max_cost": NaN}}', ["NaN"]),
        ("[1, 2]", ["JSON object", "an array"]),
        ('"robots"', ["JSON object", "a string"]),
        ("3", ["JSON object", "a number"]),
    ],
)
def test_select_not_a_json_object(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, text: str, words: list[str]
) -> None:
    code, out, err = run(capsys, "select", write(tmp_path, text))
    assert code == 2 and out == ""
    assert_one_sentence(err, *words)


def mutated(scenario: dict[str, Any], change: Any) -> dict[str, Any]:
    document = copy.deepcopy(scenario)
    change(document)
    return document


BAD_DOCUMENTS = [
    ("missing robots", lambda d: d.pop("robots"), "robocloud: robots is missing."),
    ("missing task", lambda d: d.pop("task"), "robocloud: task is missing."),
    ("unknown top field", lambda d: d.update(extra=1), "robocloud: extra is not a known field."),
    ("robots not a list", lambda d: d.update(robots={"a": 1}), "robocloud: robots: input should"),
    (
        "missing field",
        lambda d: d["robots"][2].pop("battery"),
        "robocloud: robots[2].battery is missing.",
    ),
    (
        "wrong type",
        lambda d: d["robots"][5].update(speed="fast"),
        "robocloud: robots[5].speed: input should be a valid number.",
    ),
    (
        "negative speed",
        lambda d: d["robots"][3].update(speed=-1.0),
        "robocloud: robots[3].speed: input should be greater than or equal to 0.001.",
    ),
    (
        "zero speed",
        lambda d: d["robots"][3].update(speed=0),
        "robocloud: robots[3].speed: input should be greater than or equal to 0.001.",
    ),
    (
        "bad status",
        lambda d: d["robots"][0].update(status="asleep"),
        "robocloud: robots[0].status: input should be",
    ),
    (
        "bad capability",
        lambda d: d["robots"][1]["capabilities"].update(x={"kind": "flying"}),
        "robocloud: robots[1].capabilities.x.",
    ),
    (
        "unknown priority",
        lambda d: d["task"].update(priority="urgent"),
        "robocloud: task.priority: input should be 'balanced', 'time' or 'cost'.",
    ),
    (
        "task missing field",
        lambda d: d["task"].pop("max_cost"),
        "robocloud: task.max_cost is missing.",
    ),
    (
        "task requires nothing",
        lambda d: d["task"].update(sensing={}, actuating={}),
        "robocloud: task: a task must require",
    ),
    (
        "duplicate id",
        lambda d: d["robots"][7].update(id=d["robots"][2]["id"]),
        "robocloud: robots[7].id: 'a-0003' is already the id of robots[2].",
    ),
]


@pytest.mark.parametrize(
    ("label", "change", "expected"), BAD_DOCUMENTS, ids=[b[0] for b in BAD_DOCUMENTS]
)
def test_select_bad_document(
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    small_scenario: dict[str, Any],
    label: str,
    change: Any,
    expected: str,
) -> None:
    code, out, err = run(capsys, "select", write(tmp_path, mutated(small_scenario, change)))
    assert code == 2, label
    assert out == ""
    assert_one_sentence(err)
    assert err.startswith(expected), err


@pytest.mark.parametrize(("option", "value"), [("--seed", "-2"), ("--pool-size", "0")])
def test_select_bad_options(
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    small_scenario: dict[str, Any],
    option: str,
    value: str,
) -> None:
    code, out, err = run(capsys, "select", write(tmp_path, small_scenario), option, value)
    assert code == 2 and out == ""
    assert_one_sentence(err, option)


def test_select_bad_stdin(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(sys, "stdin", io.StringIO("oops"))
    code, out, err = run(capsys, "select", "-")
    assert code == 2 and out == ""
    assert_one_sentence(err, "stdin", "not valid JSON")


# --- select: success ----------------------------------------------------------


def test_select_the_thesis_scenario(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    path = write(tmp_path, wildfire_scenario(1000, 3, 0))
    code, out, err = run(capsys, "select", path, "--optimizer", "exact")
    assert code == 0 and err == ""
    assert out.endswith("\n") and out.count("\n") == 1
    result = json.loads(out)  # exactly one document, or json.loads fails
    assert set(result) == OUTPUT_KEYS
    assert result["candidates"] == 100
    assert result["optimizer"] == "exact"
    assert result["reason"] is None
    assert result["pareto"]
    assert result["chosen"] in result["pareto"]
    assert set(result["chosen"]) == {"robots", "time", "cost", "size"}
    assert result["chosen"]["time"] <= 600 and result["chosen"]["cost"] <= 500


def test_select_from_stdin_with_options(capsys: pytest.CaptureFixture[str],
                                        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys, "stdin", io.StringIO(json.dumps(wildfire_scenario(300, 2, 1))))
    code, out, err = run(
        capsys, "select", "-", "--optimizer", "mopso", "--seed", "3", "--pool-size", "20"
    )
    assert code == 0 and err == ""
    result = json.loads(out)
    assert set(result) == OUTPUT_KEYS
    assert result["optimizer"] == "mopso"


def test_select_nothing_feasible_still_exits_0(capsys: pytest.CaptureFixture[str],
                                               tmp_path: Path,
                                               small_scenario: dict[str, Any]) -> None:
    document = mutated(small_scenario, lambda d: d["task"].update(actuating={"hose": 1}))
    code, out, err = run(capsys, "select", write(tmp_path, document))
    assert code == 0 and err == ""
    result = json.loads(out)
    assert set(result) == OUTPUT_KEYS
    assert result["pareto"] == [] and result["chosen"] is None
    assert isinstance(result["reason"], str) and result["reason"]


# --- a real process -----------------------------------------------------------


def robocloud_process(*argv: str, stdin: str = "") -> subprocess.CompletedProcess[str]:
    # The package under test, whether installed or only on the test's path.
    source = str(Path(robocloud.__file__).resolve().parent.parent)
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(p for p in (source, os.environ.get("PYTHONPATH", "")) if p),
    }
    return subprocess.run(
        [sys.executable, "-m", "robocloud.cli.main", *argv],
        input=stdin,
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
        check=False,
    )


def test_process_bad_input_is_one_sentence(tmp_path: Path, small_scenario: dict[str, Any]) -> None:
    document = mutated(small_scenario, lambda d: d["robots"][3].update(speed=-1.0))
    done = robocloud_process("select", write(tmp_path, document))
    assert done.returncode == 2
    assert done.stdout == ""
    assert done.stderr == (
        "robocloud: robots[3].speed: input should be greater than or equal to 0.001.\n"
    )


@pytest.mark.parametrize(
    ("argv", "stdin", "word"),
    [
        (["select", "-"], "{", "not valid JSON"),
        (["select", "/no/such/scenario.json"], "", "no such file"),
        (["scenario", "wildfire", "--robots", "0"], "", "--robots"),
    ],
)
def test_process_exit_2_without_traceback(argv: list[str], stdin: str, word: str) -> None:
    done = robocloud_process(*argv, stdin=stdin)
    assert done.returncode == 2
    assert "Traceback" not in done.stderr
    assert done.stderr.count("\n") == 1 and word in done.stderr


def test_process_scenario_into_select(tmp_path: Path) -> None:
    made = robocloud_process("scenario", "wildfire", "--robots", "200", "--seed", "2")
    assert made.returncode == 0
    done = robocloud_process("select", "-", stdin=made.stdout)
    assert done.returncode == 0, done.stderr
    assert set(json.loads(done.stdout)) == OUTPUT_KEYS
