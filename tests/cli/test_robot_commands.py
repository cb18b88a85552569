"""robot-check and vda5050: a wrong argument is a sentence and exit 2; no broker, exit 1."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from robocloud.cli.main import main
from robocloud.conformance import RULES
from robocloud.fleet import open_router


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
    return port


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str]:
    code = main(list(argv))
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    return code, err


CHECK = ["robot-check", "--connect", "tcp/127.0.0.1:17999", "--cloud", "cloud-a", "--robot", "r1"]


@pytest.mark.parametrize(
    ("change", "sentence"),
    [
        (["--cloud", "a/b"], "cloud 'a/b' cannot be used in a Zenoh key"),
        (["--robot", "r*"], "robot 'r*' cannot be used in a Zenoh key"),
        (["--connect", "nowhere"], "--connect 'nowhere' is not a Zenoh endpoint"),
        (["--ack-timeout", "0"], "--ack-timeout must be more than 0 and at most 3600, not 0.0."),
        (["--outage", "nan"], "--outage must be more than 0 and at most 3600, not nan."),
        (["--watch", "-1"], "--watch must be more than 0 and at most 3600, not -1.0."),
    ],
)
def test_robot_check_refuses_wrong_arguments(
    capsys: pytest.CaptureFixture[str], change: list[str], sentence: str
) -> None:
    argv = list(CHECK)
    flag, value = change
    if flag in argv:
        argv[argv.index(flag) + 1] = value
    else:
        argv += [flag, value]
    code, err = run(capsys, *argv)
    assert code == 2
    assert sentence in err, err


def test_robot_check_fails_with_a_sentence_when_no_robot_comes(
    capsys: pytest.CaptureFixture[str],
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    code = main(["robot-check", "--connect", endpoint, "--cloud", "cloud-a", "--robot", "nobody",
                 "--join-timeout", "0.5"])  # fmt: skip
    out = capsys.readouterr().out
    assert code == 1
    assert "join                 FAIL  no state on robocloud/cloud-a/robots/nobody/state" in out
    assert out.strip().endswith(f"0 passed, {len(RULES)} failed")


GATEWAY = ["vda5050", "--cloud", "cloud-a", "--connect", "tcp/127.0.0.1:17998"]


@pytest.mark.parametrize(
    ("extra", "sentence"),
    [
        (["--mqtt", "localhost"], "--mqtt 'localhost' is not HOST:PORT"),
        (["--mqtt", "127.0.0.1:99999"], "--mqtt '127.0.0.1:99999' is not HOST:PORT"),
        (["--major", "v1"], "--major 'v1' is not spoken: the gateway speaks VDA 5050 2.x (v2)."),
        (["--interface", "a/b"], "--interface 'a/b' must be one MQTT topic level"),
        (["--capabilities", "/no/such.json"], "/no/such.json: no such file."),
        (["--connect-timeout", "-1"], "--connect-timeout must be 0 to 3600 s"),
        (["--gateway-name", "a/b"], "--gateway-name 'a/b' cannot be used in a Zenoh key"),
        (["--accept-within", "0"], "--accept-within must be more than 0 and at most 600 s"),
        (["--reconcile-grace", "nan"], "--reconcile-grace must be more than 0 and at most 600"),
        (["--state-interval", "31"], "--state-interval must be more than 0 and at most 30 s"),
    ],
)
def test_vda5050_refuses_wrong_arguments(
    capsys: pytest.CaptureFixture[str], extra: list[str], sentence: str
) -> None:
    code, err = run(capsys, *GATEWAY, *extra)
    assert code == 2
    assert sentence in err, err


def test_vda5050_says_which_field_of_the_capabilities_file_is_wrong(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    caps = tmp_path / "caps.json"
    caps.write_text('{"capabilities": {"lift": {"kind": "actuating", "time": -1, "cost": 1, '
                    '"action": "pick"}}}')  # fmt: skip
    code, err = run(capsys, *GATEWAY, "--capabilities", str(caps))
    assert code == 2
    assert "caps.json: capabilities.lift.time: input should be greater than or equal to 0" in err


def test_vda5050_without_a_broker_is_one_sentence_and_exit_1(
    capsys: pytest.CaptureFixture[str],
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_router([endpoint])
    try:
        code, err = run(capsys, "vda5050", "--cloud", "cloud-a", "--connect", endpoint,
                        "--mqtt", f"127.0.0.1:{free_port()}", "--connect-timeout", "1")  # fmt: skip
    finally:
        router.close()  # type: ignore[no-untyped-call]
    assert code == 1
    assert "cannot reach the MQTT broker at 127.0.0.1:" in err
