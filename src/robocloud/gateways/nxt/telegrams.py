"""The NXT's direct-command telegrams: bytes in, bytes out, no I/O.

Written from LEGO's *Bluetooth Developer Kit* ("Appendix 2: LEGO MINDSTORMS
NXT Direct Commands" and "Communication protocol"). All multi-byte fields are
little-endian. A telegram is::

    byte 0   telegram type: 0x00 direct command, reply wanted
                            0x80 direct command, no reply
                            0x02 reply
    byte 1   command (0x04 SETOUTPUTSTATE, ...)
    byte 2.. the command's fields; a reply has a status byte here (0x00: success)

Over Bluetooth (and the stand-in's TCP) each telegram is preceded by its
length, two bytes, least significant first (``frame``).

The commands the gateway uses, with the bytes after the command byte:

=====================  =====  ============================================  ======================
command                code   fields                                         reply fields
=====================  =====  ============================================  ======================
SETOUTPUTSTATE         0x04   port u8, power s8, mode u8, regulation u8,     (status only)
                              turn ratio s8, run state u8, tacho limit u32
SETINPUTMODE           0x05   port u8, sensor type u8, sensor mode u8        (status only)
GETOUTPUTSTATE         0x06   port u8                                        port u8, power s8,
                                                                             mode u8, regulation
                                                                             u8, turn ratio s8, run
                                                                             state u8, tacho limit
                                                                             u32, tacho count s32,
                                                                             block tacho count s32,
                                                                             rotation count s32
GETINPUTVALUES         0x07   port u8                                        port u8, valid u8,
                                                                             calibrated u8, type u8,
                                                                             mode u8, raw u16,
                                                                             normalized u16, scaled
                                                                             s16, calibrated s16
RESETMOTORPOSITION     0x0A   port u8, relative u8 (1: since the last        (status only)
                              movement, 0: absolute)
GETBATTERYLEVEL        0x0B   (none)                                         millivolts u16
KEEPALIVE              0x0D   (none)                                         sleep time limit u32 ms
=====================  =====  ============================================  ======================

Output ports are 0, 1, 2 (A, B, C; 0xFF all three), input ports 0 to 3
(sensor ports 1 to 4). This codec reads and writes fields one by one with
``int.from_bytes``; the stand-in brick (``standin.py``) has its own,
``struct``-based, so each checks the other.
"""

from __future__ import annotations

from dataclasses import dataclass

DIRECT = 0x00
DIRECT_NO_REPLY = 0x80
REPLY = 0x02

SETOUTPUTSTATE = 0x04
SETINPUTMODE = 0x05
GETOUTPUTSTATE = 0x06
GETINPUTVALUES = 0x07
RESETMOTORPOSITION = 0x0A
GETBATTERYLEVEL = 0x0B
KEEPALIVE = 0x0D

# Output mode bits, regulation modes and run states (SETOUTPUTSTATE).
MOTORON = 0x01
BRAKE = 0x02
REGULATED = 0x04
REGULATION_IDLE = 0x00
REGULATION_SPEED = 0x01
RUN_IDLE = 0x00
RUN_RUNNING = 0x20

ALL_OUTPUTS = 0xFF
OUTPUT_PORTS = {"A": 0, "B": 1, "C": 2}

# Sensor types and modes (SETINPUTMODE).
SENSOR_TYPES = {
    "touch": 0x01,  # SWITCH
    "light": 0x05,  # LIGHT_ACTIVE: its red LED on, reads reflected light
    "sound": 0x07,  # SOUND_DB
    "ultrasonic": 0x0B,  # LOWSPEED_9V: an I2C sensor, read with LSWRITE/LSREAD
}
BOOLEAN_MODE = 0x20
PERCENT_MODE = 0x80  # PCTFULLSCALEMODE: scaled value 0 to 100
RAW_MODE = 0x00

STATUS_SENTENCES = {
    0x20: "a communication transaction is pending",
    0xBD: "the request failed",
    0xBE: "the command is unknown",
    0xBF: "the packet is insane",
    0xC0: "the data holds out-of-range values",
    0xDD: "the communication bus failed",
    0xDE: "the communication buffer is full",
    0xDF: "the channel or connection is not valid",
    0xE0: "the channel or connection is not configured or busy",
    0xEC: "no program is running",
    0xED: "the size is illegal",
    0xEF: "a field of a structure is invalid",
    0xF0: "the input or output port is bad",
    0xFB: "the brick has too little memory",
    0xFF: "the arguments are bad",
}

MAX_TELEGRAM = 64  # bytes: a Bluetooth telegram of the NXT is at most 64 bytes


class TelegramError(ValueError):
    """Bytes that are not the reply expected; the text is a sentence for the log."""


class BrickRefused(TelegramError):
    """A well-formed reply whose status byte is not success."""

    def __init__(self, command: int, status: int) -> None:
        sentence = STATUS_SENTENCES.get(status, "an unknown error")
        super().__init__(
            f"the brick answered command 0x{command:02X} with status 0x{status:02X}: {sentence}"
        )
        self.command = command
        self.status = status


# -- framing ----------------------------------------------------------------------------


def frame(telegram: bytes) -> bytes:
    """The telegram preceded by its length, 2 bytes little-endian (Bluetooth framing)."""
    if not 0 < len(telegram) <= MAX_TELEGRAM:
        raise TelegramError(f"a telegram is 1 to {MAX_TELEGRAM} bytes, not {len(telegram)}")
    return len(telegram).to_bytes(2, "little") + telegram


def frame_length(prefix: bytes) -> int:
    """The length a 2-byte prefix announces (checked)."""
    length = int.from_bytes(prefix[:2], "little")
    if not 0 < length <= MAX_TELEGRAM:
        raise TelegramError(f"a length prefix announces {length} bytes, not 1 to {MAX_TELEGRAM}")
    return length


# -- commands ---------------------------------------------------------------------------


def _u8(value: int) -> bytes:
    return value.to_bytes(1, "little", signed=False)


def _s8(value: int) -> bytes:
    return value.to_bytes(1, "little", signed=True)


def _kind(reply: bool) -> bytes:
    return _u8(DIRECT if reply else DIRECT_NO_REPLY)


def set_output_state(
    port: int,
    power: int,
    *,
    mode: int = MOTORON | BRAKE | REGULATED,
    regulation: int = REGULATION_SPEED,
    turn_ratio: int = 0,
    run_state: int = RUN_RUNNING,
    tacho_limit: int = 0,
    reply: bool = True,
) -> bytes:
    """Turn the motor on ``port`` at ``power`` (-100..100) for ``tacho_limit`` degrees (0: on)."""
    if not -100 <= power <= 100:
        raise TelegramError(f"a motor's power is -100 to 100, not {power}")
    if not 0 <= tacho_limit < 2**32:
        raise TelegramError(f"a tacho limit is 0 to 2^32-1 degrees, not {tacho_limit}")
    return (
        _kind(reply)
        + _u8(SETOUTPUTSTATE)
        + _u8(port)
        + _s8(power)
        + _u8(mode)
        + _u8(regulation)
        + _s8(turn_ratio)
        + _u8(run_state)
        + tacho_limit.to_bytes(4, "little")
    )


def stop_outputs(port: int = ALL_OUTPUTS, *, reply: bool = True) -> bytes:
    """Brake the motor(s): power 0, motor on and braking, regulation off."""
    return set_output_state(
        port,
        0,
        mode=MOTORON | BRAKE,
        regulation=REGULATION_IDLE,
        run_state=RUN_RUNNING,
        reply=reply,
    )


def set_input_mode(port: int, sensor_type: int, sensor_mode: int, *, reply: bool = True) -> bytes:
    return _kind(reply) + _u8(SETINPUTMODE) + _u8(port) + _u8(sensor_type) + _u8(sensor_mode)


def get_output_state(port: int) -> bytes:
    return _u8(DIRECT) + _u8(GETOUTPUTSTATE) + _u8(port)


def get_input_values(port: int) -> bytes:
    return _u8(DIRECT) + _u8(GETINPUTVALUES) + _u8(port)


def reset_motor_position(port: int, relative: bool, *, reply: bool = True) -> bytes:
    return _kind(reply) + _u8(RESETMOTORPOSITION) + _u8(port) + _u8(1 if relative else 0)


def get_battery_level() -> bytes:
    return _u8(DIRECT) + _u8(GETBATTERYLEVEL)


def keep_alive(*, reply: bool = True) -> bytes:
    return _kind(reply) + _u8(KEEPALIVE)


# -- replies ----------------------------------------------------------------------------


@dataclass(frozen=True)
class OutputState:
    port: int
    power: int
    mode: int
    regulation: int
    turn_ratio: int
    run_state: int
    tacho_limit: int
    tacho_count: int  # since the last movement was set
    block_tacho_count: int  # since the last relative reset
    rotation_count: int  # since the last absolute reset


@dataclass(frozen=True)
class InputValues:
    port: int
    valid: bool
    calibrated: bool
    sensor_type: int
    sensor_mode: int
    raw: int
    normalized: int
    scaled: int
    calibrated_value: int


REPLY_LENGTHS = {
    SETOUTPUTSTATE: 3,
    SETINPUTMODE: 3,
    GETOUTPUTSTATE: 25,
    GETINPUTVALUES: 16,
    RESETMOTORPOSITION: 3,
    GETBATTERYLEVEL: 5,
    KEEPALIVE: 7,
}


def check_reply(telegram: bytes, command: int) -> bytes:
    """The reply's fields after its status byte; TelegramError when it is not a good reply."""
    if len(telegram) < 3 or telegram[0] != REPLY:
        raise TelegramError(f"expected a reply (0x02) to 0x{command:02X}, got {telegram.hex()}")
    if telegram[1] != command:
        raise TelegramError(
            f"expected the reply to 0x{command:02X}, got one to 0x{telegram[1]:02X}"
        )
    if telegram[2] != 0:
        raise BrickRefused(command, telegram[2])
    expected = REPLY_LENGTHS.get(command)
    if expected is not None and len(telegram) != expected:
        raise TelegramError(
            f"the reply to 0x{command:02X} is {len(telegram)} bytes, not {expected}"
        )
    return telegram[3:]


def _field(data: bytes, start: int, size: int, signed: bool) -> int:
    return int.from_bytes(data[start : start + size], "little", signed=signed)


def parse_output_state(telegram: bytes) -> OutputState:
    data = check_reply(telegram, GETOUTPUTSTATE)
    return OutputState(
        port=_field(data, 0, 1, False),
        power=_field(data, 1, 1, True),
        mode=_field(data, 2, 1, False),
        regulation=_field(data, 3, 1, False),
        turn_ratio=_field(data, 4, 1, True),
        run_state=_field(data, 5, 1, False),
        tacho_limit=_field(data, 6, 4, False),
        tacho_count=_field(data, 10, 4, True),
        block_tacho_count=_field(data, 14, 4, True),
        rotation_count=_field(data, 18, 4, True),
    )


def parse_input_values(telegram: bytes) -> InputValues:
    data = check_reply(telegram, GETINPUTVALUES)
    return InputValues(
        port=_field(data, 0, 1, False),
        valid=data[1] != 0,
        calibrated=data[2] != 0,
        sensor_type=_field(data, 3, 1, False),
        sensor_mode=_field(data, 4, 1, False),
        raw=_field(data, 5, 2, False),
        normalized=_field(data, 7, 2, False),
        scaled=_field(data, 9, 2, True),
        calibrated_value=_field(data, 11, 2, True),
    )


def parse_battery_level(telegram: bytes) -> int:
    """Millivolts."""
    return _field(check_reply(telegram, GETBATTERYLEVEL), 0, 2, False)


def parse_keep_alive(telegram: bytes) -> int:
    """The brick's sleep time limit, milliseconds."""
    return _field(check_reply(telegram, KEEPALIVE), 0, 4, False)


def parse_status(telegram: bytes, command: int) -> None:
    """A reply of status only (SETOUTPUTSTATE, SETINPUTMODE, RESETMOTORPOSITION)."""
    check_reply(telegram, command)
