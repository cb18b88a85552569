"""robocloud nxt and nxt-brick: a wrong argument or bricks file is a sentence and exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from robocloud.cli import demo
from robocloud.cli.main import build_parser, main

EXAMPLE = Path(__file__).parents[2] / "examples" / "nxt" / "thesis-bricks.json"
GATEWAY = ["nxt", "--cloud", "cloud-a", "--connect", "tcp/127.0.0.1:17996"]


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str]:
    code = main(list(argv))
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    return code, err


@pytest.mark.parametrize(
    ("extra", "sentence"),
    [
        (["--bricks", "/no/such.json"], "/no/such.json: no such file."),
        (["--bricks", str(EXAMPLE), "--gateway-name", "a/b"], "--gateway-name 'a/b' cannot be"),
        (["--bricks", str(EXAMPLE), "--connect-timeout", "nan"], "--connect-timeout must be"),
    ],
)
def test_nxt_refuses_wrong_arguments(
    capsys: pytest.CaptureFixture[str], extra: list[str], sentence: str
) -> None:
    code, err = run(capsys, *GATEWAY, *extra)
    assert code == 2
    assert sentence in err, err


def test_nxt_says_which_field_of_the_bricks_file_is_wrong(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    data = json.loads(EXAMPLE.read_text())
    data["robots"]["nxt-tribot"]["build"]["arm"]["close"] = "shut"
    bricks = tmp_path / "bricks.json"
    bricks.write_text(json.dumps(data))
    code, err = run(capsys, *GATEWAY, "--bricks", str(bricks))
    assert code == 2
    assert "bricks.json: robots.nxt-tribot.build.arm.close: input should be a valid integer" in err
    bricks.write_text("{")
    code, err = run(capsys, *GATEWAY, "--bricks", str(bricks))
    assert (code, "is not valid JSON" in err) == (2, True), err


@pytest.mark.parametrize(
    ("extra", "sentence"),
    [
        (["--robot", "nobody"], "--robot 'nobody' is not in"),
        (["--robot", "nxt-tribot", "--obstacle", "1"], "--obstacle '1' is not X,Y or X,Y,R"),
        (["--robot", "nxt-tribot", "--obstacle", "1,2,0"], "the radius must be more than 0"),
        (["--robot", "nxt-tribot", "--speedup", "0"], "--speedup must be more than 0"),
        (["--robot", "nxt-tribot", "--battery-mv", "-5"], "--battery-mv must be 0 to 10000"),
    ],
)
def test_the_stand_in_refuses_wrong_arguments(
    capsys: pytest.CaptureFixture[str], extra: list[str], sentence: str
) -> None:
    code, err = run(capsys, "nxt-brick", "--bricks", str(EXAMPLE), *extra)
    assert code == 2
    assert sentence in err, err


def test_a_stand_in_needs_a_tcp_reach(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    data = json.loads(EXAMPLE.read_text())
    data["robots"]["nxt-tribot"]["reach"] = {"bluetooth": "00:16:53:0A:1B:2C"}
    bricks = tmp_path / "bricks.json"
    bricks.write_text(json.dumps(data))
    code, err = run(capsys, "nxt-brick", "--bricks", str(bricks), "--robot", "nxt-tribot")
    assert code == 2
    assert "is reached over Bluetooth" in err and "needs reach.tcp" in err


def test_make_run_with_nxt_adds_three_stand_ins_and_a_gateway_to_the_first_cloud(
    tmp_path: Path,
) -> None:
    members, parts = demo.plan(demo.parse_args(["--nxt", "--var", str(tmp_path)]), "k")
    nxt = [p for p in parts if p.argv[0] in ("nxt", "nxt-brick")]
    assert [p.argv[0] for p in nxt] == ["nxt-brick"] * 3 + ["nxt"]
    assert {p.group for p in nxt} == {members[0].cloud}
    gateway = nxt[-1]
    assert gateway.argv[gateway.argv.index("--connect") + 1] == members[0].zenoh
    parser = build_parser()
    for part in nxt:  # each is a command robocloud accepts
        parsed = parser.parse_args(part.argv)
        assert Path(parsed.bricks) == demo.NXT_BRICKS and demo.NXT_BRICKS.exists()
    assert parts[-1].title == "the Wildfire Suppression Application"
    _, without = demo.plan(demo.parse_args(["--var", str(tmp_path)]), "k")
    assert not [p for p in without if p.argv[0].startswith("nxt")]
