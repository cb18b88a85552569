"""The robots file of ``robocloud ros2``: checked whole before anything opens, with a sentence."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from robocloud.cli.main import main
from robocloud.errors import InvalidInput, NotFound
from robocloud.gateways.ros2.robots_file import Offset, load_robots, parse_robots


def entry(**changes: Any) -> dict[str, Any]:
    base = {
        "endpoint": "tcp/127.0.0.1:7501",
        "scheme": "rmw_zenoh",
        "domain": 0,
        "namespace": "",
        "distro": "jazzy",
        "offset": {"x": 0, "y": 0, "yaw": 0},
        "speed": 0.5,
        "capabilities": {"camera": {"kind": "sensing", "time": 5, "cost": 1}},
    }
    return {**base, **changes}


def test_the_issues_shape_is_read() -> None:
    robots = parse_robots({"robots": {"tb4-1": entry(), "amr/2"[:3]: entry(
        endpoint="tcp/127.0.0.1:7502", scheme="bridge", namespace="/bot2", distro="humble")}},
        "f")  # fmt: skip
    assert set(robots.robots) == {"tb4-1", "amr"}
    assert robots.robots["amr"].namespace == "/bot2"
    assert robots.robots["tb4-1"].action == "navigate_to_pose"
    assert robots.cost_per_m("tb4-1") == 0.05


@pytest.mark.parametrize(
    ("robots", "sentence"),
    [
        ({}, "robots is missing"),
        ({"robots": {}}, "robots: "),
        ({"robots": {"r": entry(scheme="dds")}}, "robots.r.scheme"),
        ({"robots": {"r": entry(distro="iron")}}, "robots.r.distro"),
        ({"robots": {"r": entry(speed=0)}}, "robots.r.speed"),
        ({"robots": {"r": entry(endpoint="127.0.0.1:7447")}}, "Zenoh endpoint"),
        ({"robots": {"r": entry(namespace="bad ns")}}, "robots.r.namespace"),
        ({"robots": {"r": entry(offset={"x": 0, "y": 0, "yaw": math.inf})}}, "robots.r.offset.yaw"),
        ({"robots": {"r": entry(colour="red")}}, "robots.r.colour is not a known field"),
        ({"robots": {"a": entry(), "b": entry()}}, "robots a and b have the same endpoint"),
    ],
)
def test_a_bad_file_is_refused_with_a_sentence_naming_the_field(
    robots: dict[str, Any], sentence: str
) -> None:
    with pytest.raises(InvalidInput, match=sentence.replace(".", r"\.")):
        parse_robots(robots, "robots.json")


def test_the_file_itself_is_checked(tmp_path: Path) -> None:
    with pytest.raises(NotFound, match="no such file"):
        load_robots(str(tmp_path / "none.json"))
    bad = tmp_path / "bad.json"
    bad.write_text("{robots")
    with pytest.raises(InvalidInput, match="not valid JSON"):
        load_robots(str(bad))


def test_the_command_exits_2_with_the_sentence_before_opening_anything(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "robots.json"
    path.write_text(json.dumps({"robots": {"r": entry(distro="rolling")}}))
    code = main(["ros2", "--cloud", "cloud-a", "--connect", "tcp/127.0.0.1:1",
                 "--robots", str(path)])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2
    assert "robots.r.distro" in err and "Traceback" not in err


@given(
    st.floats(-1e4, 1e4), st.floats(-1e4, 1e4), st.floats(-math.pi, math.pi),
    st.floats(-1e4, 1e4), st.floats(-1e4, 1e4),
)  # fmt: skip
def test_the_offset_maps_to_the_cloud_and_back(
    ox: float, oy: float, yaw: float, x: float, y: float
) -> None:
    offset = Offset(x=ox, y=oy, yaw=yaw)
    cx, cy = offset.to_cloud(x, y)
    assert math.hypot(cx - ox, cy - oy) == pytest.approx(math.hypot(x, y), abs=1e-6)
    bx, by = offset.to_map(cx, cy)
    assert (bx, by) == (pytest.approx(x, abs=1e-6), pytest.approx(y, abs=1e-6))


def test_a_quarter_turn_offset() -> None:
    # cloud = (100, 0) + R(90 degrees) * map: the map's x axis is the cloud's y axis.
    cx, cy = Offset(x=100, y=0, yaw=math.pi / 2).to_cloud(5, 0)
    assert (cx, cy) == (pytest.approx(100), pytest.approx(5))
