"""rmw_zenoh's keys, liveliness tokens and attachment, from ros2/rmw_zenoh's docs/design.md."""

from __future__ import annotations

import struct

import pytest

from robocloud.gateways.ros2 import naming

HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"


def test_a_data_key_is_domain_name_type_and_hash() -> None:
    # design.md's examples: the chatter topic, then under the namespace /robot1.
    string = "std_msgs::msg::dds_::String_"
    assert naming.rmw_key(0, "", "chatter", string, HASH) == f"0/chatter/{string}/{HASH}"
    assert naming.rmw_key(0, "/robot1", "chatter", string, HASH) == (
        f"0/robot1/chatter/{string}/{HASH}"
    )
    assert naming.bridge_key("/bot2", naming.action_entity("navigate_to_pose", "send_goal")) == (
        "bot2/navigate_to_pose/_action/send_goal"
    )


def test_a_service_servers_token_is_parsed_as_design_md_writes_it() -> None:
    key = (
        "@ros2_lv/2/f9980ee0495eaafb3e38f0d19e2eae12/0/10/SS/%/%/add_two_ints_server/"
        "%add_two_ints/example_interfaces::srv::dds_::AddTwoInts_/"
        "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a/::,10:,:,:,,"
    )
    token = naming.parse_token(key)
    assert token is not None
    assert (token.domain, token.kind, token.name) == (2, "SS", "add_two_ints")
    assert token.dds_type == "example_interfaces::srv::dds_::AddTwoInts_"
    assert token.type_hash.startswith("RIHS01_e118")
    node = naming.parse_token("@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener")
    assert node is not None and node.kind == "NN" and node.node == "listener"
    assert naming.parse_token("0/chatter/x/y") is None
    assert naming.parse_token("@ros2_lv/x/a/0/0/NN/%/%/n") is None


def test_the_tokens_made_for_the_stand_in_parse_back() -> None:
    key = naming.token_key(
        0,
        "abc",
        0,
        10,
        "SS",
        "/bot1",
        "bt_navigator",
        "/bot1/navigate_to_pose/_action/send_goal",
        "nav2_msgs::action::dds_::NavigateToPose_SendGoal_",
        naming.NO_HASH,
    )
    assert "/%bot1/bt_navigator/%bot1%navigate_to_pose%_action%send_goal/" in key
    token = naming.parse_token(key)
    assert token is not None
    assert token.name == "bot1/navigate_to_pose/_action/send_goal"
    assert token.namespace == "/bot1" and token.type_hash == naming.NO_HASH


def test_the_attachment_is_33_little_endian_bytes() -> None:
    gid = bytes(range(16))
    raw = naming.Attachment(7, 1_700_000_000_123_456_789, gid).encode()
    assert len(raw) == 33
    assert raw[:8] == (7).to_bytes(8, "little")
    assert raw[16] == 16 and raw[17:] == gid
    assert naming.decode_attachment(raw) == naming.Attachment(7, 1_700_000_000_123_456_789, gid)


def test_the_older_keyed_attachment_is_read_with_or_without_the_gids_length() -> None:
    gid = bytes(range(100, 116))
    older = naming.Attachment(42, 99, gid)
    keyed = naming.encode_keyed_attachment(older)
    assert len(keyed) > 33
    assert naming.decode_attachment(keyed) == older
    without_length = keyed[:-17] + gid  # a fixed array: no length before the GID
    assert naming.decode_attachment(without_length) == older


@pytest.mark.parametrize(
    ("raw", "why"),
    [
        (b"", "ends early"),
        (struct.pack("<qqB16s", 1, 2, 8, bytes(16)), "GID length byte is 8"),
        (b"\x0fsequence_number" + bytes(4), "ends inside a number"),
        (bytes(32), "no sequence_number"),
    ],
)
def test_any_other_attachment_is_refused_with_a_reason(raw: bytes, why: str) -> None:
    with pytest.raises(naming.AttachmentError, match=why):
        naming.decode_attachment(raw)
