"""Per-robot identities: the access control a robot's own certificate gets, and ``--robot-ids``.

The attack with real processes is tests/system/test_robot_identities.py.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.x509.oid import NameOID

from robocloud.errors import InvalidInput
from robocloud.federation.security import OverlaySecurity, access_control, make_certs
from robocloud.federation.security.configuration import read_robot_ids
from robocloud.federation.security.policy import robot_name


def test_a_robot_certificate_gets_its_own_state_and_command_keys_only() -> None:
    acl = access_control("cloud-b", ["cloud-a"], robot_ids=["b-7", "b-8"])
    rules = {rule["id"]: rule for rule in acl["rules"]}
    policies = {policy["id"]: policy for policy in acl["policies"]}
    assert {"id": "robot-b-7", "cert_common_names": ["cloud-b-robot-b-7"]} in acl["subjects"]
    assert policies["robot-b-7"] == {
        "id": "robot-b-7",
        "subjects": ["robot-b-7"],
        "rules": ["state-of-b-7", "commands-of-b-7"],
    }
    assert rules["state-of-b-7"]["messages"] == ["put"]
    assert rules["state-of-b-7"]["key_exprs"] == ["robocloud/cloud-b/robots/b-7/state"]
    assert rules["commands-of-b-7"]["messages"] == ["declare_queryable", "reply"]
    assert rules["commands-of-b-7"]["key_exprs"] == ["robocloud/cloud-b/robots/b-7/cmd"]
    assert rules["state-of-b-8"]["key_exprs"] == ["robocloud/cloud-b/robots/b-8/state"]
    # The fleet's certificate is unchanged: it still speaks for every robot of its cloud.
    assert rules["fleet-states"]["key_exprs"][0] == "robocloud/cloud-b/robots/*/state"
    assert "robot-b-7" not in {p["id"] for p in access_control("cloud-b", ["cloud-a"])["policies"]}


def test_robot_ids_are_key_chunks_each_once() -> None:
    with pytest.raises(InvalidInput, match="listed twice"):
        access_control("cloud-b", ["cloud-a"], robot_ids=["b-7", "b-7"])
    with pytest.raises(InvalidInput, match="robot id 'b/7'"):
        access_control("cloud-b", ["cloud-a"], robot_ids=["b/7"])


def test_the_robot_ids_file_is_one_id_a_line(tmp_path: Path) -> None:
    path = tmp_path / "ids.txt"
    path.write_text("# cloud-b's robots with their own certificate\nb-7\n\n  b-8  \n")
    assert read_robot_ids(path) == ("b-7", "b-8")
    path.write_text("# nothing\n\n")
    with pytest.raises(InvalidInput, match="lists no robot id"):
        read_robot_ids(path)
    with pytest.raises(InvalidInput, match="does not exist"):
        read_robot_ids(tmp_path / "missing.txt")


@pytest.mark.parametrize(
    ("flag", "text", "options"),
    [
        ("--robot-ids", "b-7\n", {"robot_ids": ("b-7",)}),
        ("--gateways", "gw-1 b-1\n", {"gateways": (("gw-1", ("b-1",)),)}),
    ],
)
def test_own_certificates_need_mutual_tls(
    tmp_path: Path, flag: str, text: str, options: dict[str, object]
) -> None:
    with pytest.raises(InvalidInput, match="need mutual TLS"):
        OverlaySecurity(**options)  # type: ignore[arg-type]
    path = tmp_path / "names.txt"
    path.write_text(text)
    iaas = [sys.executable, "-m", "robocloud.cli.main", "iaas", "--cloud", "cloud-b"]
    done = subprocess.run(
        [*iaas, flag, str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        stdin=subprocess.DEVNULL,
    )
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr and "need mutual TLS" in done.stderr


def test_make_certs_makes_a_robots_certificate(tmp_path: Path) -> None:
    _, issued = make_certs(tmp_path, [robot_name("cloud-b", "b-7")])
    cert = x509.load_pem_x509_certificate(issued["cloud-b-robot-b-7"].cert.read_bytes())
    [cn] = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    assert cn.value == "cloud-b-robot-b-7"
    ids = tmp_path / "ids.txt"
    ids.write_text("b-7\n")
    made = OverlaySecurity.from_options(
        ca=tmp_path / "ca.pem",
        cert=issued["cloud-b-robot-b-7"].cert,
        key=issued["cloud-b-robot-b-7"].key,
        robot_ids_file=ids,
    )
    assert made is not None
    entries = made.for_cloud("cloud-b", ["cloud-a"]).config_entries("router")
    assert {"id": "robot-b-7", "cert_common_names": ["cloud-b-robot-b-7"]} in entries[
        "access_control"
    ]["subjects"]


def test_a_gateway_certificate_gets_its_robots_keys_only() -> None:
    acl = access_control("cloud-b", ["cloud-a"], gateways=[("gw-1", ["b-1", "b-2"])])
    rules = {rule["id"]: rule for rule in acl["rules"]}
    assert {"id": "gateway-gw-1", "cert_common_names": ["cloud-b-gateway-gw-1"]} in acl[
        "subjects"
    ]
    assert rules["gateway-gw-1-states"]["messages"] == ["put"]
    assert rules["gateway-gw-1-states"]["key_exprs"] == [
        "robocloud/cloud-b/fleets/gw-1/states",
        "robocloud/cloud-b/robots/b-1/state",
        "robocloud/cloud-b/robots/b-2/state",
    ]
    assert rules["gateway-gw-1-commands"]["messages"] == ["declare_queryable", "reply"]
    assert rules["gateway-gw-1-commands"]["key_exprs"] == [
        "robocloud/cloud-b/robots/b-1/cmd",
        "robocloud/cloud-b/robots/b-2/cmd",
    ]


def test_the_gateways_file_is_a_gateway_a_line_with_its_robots(tmp_path: Path) -> None:
    from robocloud.federation.security.configuration import read_gateways

    path = tmp_path / "gateways.txt"
    path.write_text("# cloud-b's gateways\ngw-1 b-1 b-2\n\n  gw-2   b-3  \n")
    assert read_gateways(path) == (("gw-1", ("b-1", "b-2")), ("gw-2", ("b-3",)))
    for text, sentence in (
        ("gw-1\n", "names gateway 'gw-1' but no robot"),
        ("gw-1 b-1\ngw-1 b-2\n", "gateway 'gw-1' is listed twice"),
        ("gw-1 b-1\ngw-2 b-1\n", "robot 'b-1' is listed for gateways 'gw-1' and 'gw-2'"),
        ("gw/1 b-1\n", "gateway name 'gw/1'"),
        ("# none\n", "lists no gateway"),
    ):
        path.write_text(text)
        with pytest.raises(InvalidInput, match=sentence):
            read_gateways(path)
