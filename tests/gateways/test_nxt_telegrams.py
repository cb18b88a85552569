"""The direct-command codec against the byte layouts of LEGO's Bluetooth Developer Kit.

Every expected byte string below is written out by hand from the
specification's tables (little-endian fields), not produced by the codec.
The last tests play the product's telegrams against the stand-in's own
(struct-based) codec, so each implementation checks the other.
"""

from __future__ import annotations

import pytest

from robocloud.gateways.nxt import telegrams as t
from robocloud.gateways.nxt.bricks import parse_bricks
from robocloud.gateways.nxt.standin import SimBrick, World

EXAMPLE_BRICK = {
    "reach": {"tcp": "127.0.0.1:7101"},
    "build": {"left": "B", "right": "C", "wheel_diameter": 0.056, "track_width": 0.112},
    "sensors": {"3": "light"},
}


def test_set_output_state_forward_with_a_tacho_limit() -> None:
    # Motor B (port 1) at power 75, on+brake+regulated, speed regulation, running, 360 degrees.
    telegram = t.set_output_state(1, 75, tacho_limit=360)
    assert telegram == bytes.fromhex("00 04 01 4B 07 01 00 20 68 01 00 00")


def test_set_output_state_backwards_without_reply() -> None:
    # Power -75 is 0xB5 as a signed byte; 0x80: no reply wanted; 100000 = 0x000186A0.
    telegram = t.set_output_state(2, -75, tacho_limit=100_000, reply=False)
    assert telegram == bytes.fromhex("80 04 02 B5 07 01 00 20 A0 86 01 00")


def test_stop_brakes_every_motor() -> None:
    assert t.stop_outputs() == bytes.fromhex("00 04 FF 00 03 00 00 20 00 00 00 00")


def test_the_other_commands() -> None:
    assert t.set_input_mode(2, t.SENSOR_TYPES["light"], t.PERCENT_MODE) == bytes.fromhex(
        "00 05 02 05 80"
    )
    assert t.set_input_mode(0, t.SENSOR_TYPES["touch"], t.BOOLEAN_MODE) == bytes.fromhex(
        "00 05 00 01 20"
    )
    assert t.get_output_state(0) == bytes.fromhex("00 06 00")
    assert t.get_input_values(3) == bytes.fromhex("00 07 03")
    assert t.reset_motor_position(1, relative=True) == bytes.fromhex("00 0A 01 01")
    assert t.reset_motor_position(2, relative=False) == bytes.fromhex("00 0A 02 00")
    assert t.get_battery_level() == bytes.fromhex("00 0B")
    assert t.keep_alive() == bytes.fromhex("00 0D")


def test_bluetooth_framing_is_a_little_endian_length() -> None:
    assert t.frame(bytes.fromhex("00 0B")) == bytes.fromhex("02 00 00 0B")
    assert t.frame(t.set_output_state(0, 1)).startswith(bytes.fromhex("0C 00"))
    assert t.frame_length(bytes.fromhex("19 00")) == 25
    with pytest.raises(t.TelegramError, match="announces 0 bytes"):
        t.frame_length(b"\x00\x00")
    with pytest.raises(t.TelegramError, match="announces 65535 bytes"):
        t.frame_length(b"\xff\xff")


def test_get_output_state_reply() -> None:
    reply = bytes.fromhex(
        "02 06 00"  # reply to GETOUTPUTSTATE, success
        "01 4B 07 01 00 20"  # port B, power 75, mode, regulation, turn ratio 0, running
        "68 01 00 00"  # tacho limit 360
        "2C 01 00 00"  # tacho count 300
        "FF FF FF FF"  # block tacho count -1
        "18 FC FF FF"  # rotation count -1000
    )
    state = t.parse_output_state(reply)
    assert state == t.OutputState(1, 75, 7, 1, 0, 0x20, 360, 300, -1, -1000)


def test_get_input_values_reply() -> None:
    reply = bytes.fromhex(
        "02 07 00"
        "02 01 00 05 80"  # port 3, valid, not calibrated, LIGHT_ACTIVE, PCTFULLSCALE
        "F4 01 F4 01"  # raw 500, normalized 500
        "3E 00 00 00"  # scaled 62, calibrated 0
    )
    values = t.parse_input_values(reply)
    assert (values.port, values.valid, values.sensor_type, values.scaled) == (2, True, 5, 62)
    assert (values.raw, values.normalized, values.calibrated_value) == (500, 500, 0)


def test_battery_and_keep_alive_replies() -> None:
    assert t.parse_battery_level(bytes.fromhex("02 0B 00 78 1E")) == 7800
    assert t.parse_keep_alive(bytes.fromhex("02 0D 00 C0 27 09 00")) == 600_000


def test_a_refusal_names_its_status() -> None:
    with pytest.raises(t.BrickRefused, match="0xC0: the data holds out-of-range values"):
        t.parse_status(bytes.fromhex("02 04 C0"), t.SETOUTPUTSTATE)


@pytest.mark.parametrize(
    ("reply", "words"),
    [
        ("00 0B 00 78 1E", "expected a reply"),
        ("02 0D 00 78 1E", "got one to 0x0D"),
        ("02 0B 00 78", "is 4 bytes, not 5"),
        ("02", "expected a reply"),
    ],
)
def test_a_reply_that_is_not_the_one_expected_is_refused(reply: str, words: str) -> None:
    with pytest.raises(t.TelegramError, match=words):
        t.parse_battery_level(bytes.fromhex(reply))


def test_values_outside_the_fields_are_refused() -> None:
    with pytest.raises(t.TelegramError, match="-100 to 100"):
        t.set_output_state(0, 101)
    with pytest.raises(t.TelegramError, match="tacho limit"):
        t.set_output_state(0, 50, tacho_limit=-1)


# -- the product's codec against the stand-in's ------------------------------------------------


@pytest.fixture
def sim() -> SimBrick:
    config = parse_bricks({"robots": {"b": EXAMPLE_BRICK}}, "test").robots["b"]
    clock = [100.0]
    brick = SimBrick(config, World([(0.1, 0.0, 0.05)]), millivolts=7800, clock=lambda: clock[0])
    brick.clock_value = clock  # type: ignore[attr-defined]
    return brick


def answer(sim: SimBrick, telegram: bytes) -> bytes:
    reply, _ = sim.answer(telegram)
    assert reply is not None
    return reply


def test_the_stand_in_understands_the_products_telegrams(sim: SimBrick) -> None:
    assert t.parse_battery_level(answer(sim, t.get_battery_level())) == 7800
    assert t.parse_keep_alive(answer(sim, t.keep_alive())) == 600_000
    t.parse_status(answer(sim, t.set_input_mode(2, 0x05, t.PERCENT_MODE)), t.SETINPUTMODE)
    light = t.parse_input_values(answer(sim, t.get_input_values(2)))
    assert (light.sensor_type, light.sensor_mode, light.valid) == (0x05, t.PERCENT_MODE, True)
    assert light.scaled == 62  # the obstacle 0.1 m ahead, where the sensor looks
    t.parse_status(answer(sim, t.set_output_state(1, 50, tacho_limit=90)), t.SETOUTPUTSTATE)
    sim.clock_value[0] += 10.0  # type: ignore[attr-defined]
    state = t.parse_output_state(answer(sim, t.get_output_state(1)))
    # It stops at its limit having coasted 0.015 s of its 450 deg/s past it: 96.75 degrees.
    assert (state.port, state.tacho_limit) == (1, 90)
    assert (state.tacho_count, state.rotation_count) == (96, 96)
    assert (state.power, state.run_state) == (0, t.RUN_IDLE)
    t.parse_status(answer(sim, t.reset_motor_position(1, relative=False)), t.RESETMOTORPOSITION)
    assert t.parse_output_state(answer(sim, t.get_output_state(1))).rotation_count == 0
    assert sim.answer(t.stop_outputs(reply=False))[0] is None


def test_the_stand_in_refuses_what_the_specification_refuses(sim: SimBrick) -> None:
    with pytest.raises(t.BrickRefused, match="0xF0"):
        t.parse_output_state(answer(sim, t.get_output_state(5)))
    with pytest.raises(t.BrickRefused, match="0xBE"):
        t.parse_status(answer(sim, bytes.fromhex("00 42")), 0x42)
