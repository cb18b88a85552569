"""A stand-in NXT brick: the direct commands over TCP, simulated motors, sensors and battery.

``robocloud nxt-brick --bricks FILE --robot ID`` plays the brick the bricks
file describes for ``ID`` (its build, sensors, battery and start pose) on the
``tcp`` address of its ``reach``, for tests and for anyone without an NXT.

- **Codec**: its own, a table of ``struct`` formats per command (``FORMATS``),
  written from the same specification as ``telegrams.py`` but not sharing a
  line with it, so each checks the other. Telegrams are framed as over
  Bluetooth (2-byte little-endian length).
- **Motors**: a motor at power ``p`` turns ``DEGREES_PER_POWER * p`` degrees a
  second (900 deg/s at full power, the NXT motor's unloaded speed), times
  ``--speedup``; it stops by itself at its tacho limit (run state IDLE),
  having coasted ``COAST`` seconds of its speed past it, as a real one does.
  The wheels never slip: the pose follows the drive motors exactly (an arc
  for each stretch of constant powers).
- **Sensors**: the light sensor (``LIGHT_AHEAD`` m in front of the brick)
  reads ``RED`` percent over a red obstacle (``--obstacle X,Y[,R]``) and
  ``FLOOR`` elsewhere; touch reads released, sound quiet, ultrasonic nothing.
- **Battery**: starts at ``--battery-mv`` and drains with time and motor power.
- **Faults**: ``--stall PORT`` (that motor never turns, however driven),
  ``--silent-after S`` (reads telegrams but answers none after S seconds),
  a low ``--battery-mv``; a SIGSTOP makes it silent too.
- **Log** (``--log FILE``): one JSON line per motor command and per sensor
  read with the wall time, the powers and the true pose, for tests to check.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import socket
import struct
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import IO, Any

from robocloud.errors import InvalidInput, Unavailable
from robocloud.gateways.nxt.bricks import BrickConfig, load_bricks

DEGREES_PER_POWER = 9.0  # degrees a second per percent of power
COAST = 0.015  # seconds of its speed a motor turns past its tacho limit before it stops
LIGHT_AHEAD = 0.1  # metres from the brick's centre to where the light sensor looks
RED, FLOOR = 62, 35  # percent: reflected light over a red obstacle, over the floor
IDLE_DRAIN = 0.1  # mV a second (an idle brick lasts hours)
MOTOR_DRAIN = 1.0  # mV a second per motor at full power
SLEEP_LIMIT_MS = 10 * 60 * 1000

# command -> (the request's fields after the command byte, the reply's fields after the status)
FORMATS: dict[int, tuple[str, str]] = {
    0x04: ("<BbBBbBI", "<"),  # SETOUTPUTSTATE
    0x05: ("<BBB", "<"),  # SETINPUTMODE
    0x06: ("<B", "<BbBBbBIiii"),  # GETOUTPUTSTATE
    0x07: ("<B", "<B??BBHHhh"),  # GETINPUTVALUES
    0x0A: ("<B?", "<"),  # RESETMOTORPOSITION
    0x0B: ("<", "<H"),  # GETBATTERYLEVEL
    0x0D: ("<", "<I"),  # KEEPALIVE
}
UNKNOWN_COMMAND, BAD_PORT, BAD_PACKET = 0xBE, 0xF0, 0xBF


@dataclass
class SimMotor:
    power: int = 0
    mode: int = 0
    regulation: int = 0
    turn_ratio: int = 0
    run_state: int = 0
    limit: int = 0
    tacho: float = 0.0  # since the last SETOUTPUTSTATE
    block: float = 0.0
    rotation: float = 0.0
    stalled: bool = False

    def rate(self, speedup: float) -> float:
        """Degrees a second now (signed)."""
        if self.stalled or self.run_state == 0 or not self.mode & 0x01:
            return 0.0
        return DEGREES_PER_POWER * self.power * speedup

    def stop_at(self) -> float:
        """Degrees from the start of the movement where the motor comes to rest."""
        return self.limit + DEGREES_PER_POWER * abs(self.power) * COAST

    def time_to_limit(self, speedup: float) -> float:
        rate = self.rate(speedup)
        if rate == 0.0 or self.limit == 0:
            return math.inf
        return max(0.0, (self.stop_at() - abs(self.tacho)) / abs(rate))

    def turn(self, seconds: float, speedup: float) -> float:
        degrees = self.rate(speedup) * seconds
        self.tacho += degrees
        self.block += degrees
        self.rotation += degrees
        if self.limit and abs(self.tacho) >= self.stop_at() - 1e-9:
            self.power, self.run_state = 0, 0
        return degrees


@dataclass
class World:
    obstacles: list[tuple[float, float, float]] = field(default_factory=list)

    def light(self, x: float, y: float) -> int:
        red = any(math.hypot(x - ox, y - oy) <= r for ox, oy, r in self.obstacles)
        return RED if red else FLOOR


class SimBrick:
    """The brick's physics, advanced to the time of each telegram."""

    def __init__(
        self,
        config: BrickConfig,
        world: World,
        *,
        speedup: float = 1.0,
        millivolts: float = 8600.0,
        stalled: tuple[str, ...] = (),
        clock: Any = time.monotonic,
    ) -> None:
        self.config = config
        self.world = world
        self.speedup = speedup
        self.millivolts = millivolts
        self.clock = clock
        self.motors = [SimMotor(stalled="ABC"[i] in stalled) for i in range(3)]
        self.inputs: dict[int, tuple[int, int]] = {}  # port -> type, mode
        self.x, self.y = config.start.x, config.start.y
        self.heading = math.radians(config.start.heading)
        self.at = clock()
        build = config.build
        self.left, self.right = "ABC".index(build.left), "ABC".index(build.right)
        self.wheel = math.pi * build.wheel_diameter / 360.0  # metres a degree
        self.track = build.track_width

    def advance(self) -> None:
        now = self.clock()
        remaining = now - self.at
        self.at = now
        while remaining > 0:
            # Up to the next motor that reaches its limit: every rate is constant till then.
            step = min([remaining, *(m.time_to_limit(self.speedup) for m in self.motors)])
            step = max(step, 1e-9)
            vl = self.motors[self.left].rate(self.speedup) * self.wheel
            vr = self.motors[self.right].rate(self.speedup) * self.wheel
            self._drive(vl, vr, step)
            power = sum(abs(m.power) for m in self.motors if m.rate(self.speedup))
            self.millivolts -= (IDLE_DRAIN + MOTOR_DRAIN * power / 100.0) * step * self.speedup
            for motor in self.motors:
                motor.turn(step, self.speedup)
            remaining -= step
        self.millivolts = max(self.millivolts, 0.0)

    def _drive(self, vl: float, vr: float, seconds: float) -> None:
        v, w = (vl + vr) / 2.0, (vr - vl) / self.track
        if abs(w) < 1e-12:
            self.x += v * seconds * math.cos(self.heading)
            self.y += v * seconds * math.sin(self.heading)
            return
        after = self.heading + w * seconds
        self.x += v / w * (math.sin(after) - math.sin(self.heading))
        self.y -= v / w * (math.cos(after) - math.cos(self.heading))
        self.heading = math.remainder(after, math.tau)

    def light(self) -> int:
        return self.world.light(
            self.x + LIGHT_AHEAD * math.cos(self.heading),
            self.y + LIGHT_AHEAD * math.sin(self.heading),
        )

    # -- telegrams ---------------------------------------------------------------------

    def answer(self, telegram: bytes) -> tuple[bytes | None, dict[str, Any] | None]:
        """The reply to ``telegram`` (None when none is wanted) and what to log, if anything."""
        if len(telegram) < 2 or telegram[0] not in (0x00, 0x80):
            return None, None
        wants_reply = telegram[0] == 0x00
        command = telegram[1]
        formats = FORMATS.get(command)
        if formats is None:
            return (
                struct.pack("<BBB", 0x02, command, UNKNOWN_COMMAND) if wants_reply else None
            ), None
        request, reply = formats
        try:
            fields = struct.unpack(request, telegram[2:])
        except struct.error:
            return (struct.pack("<BBB", 0x02, command, BAD_PACKET) if wants_reply else None), None
        self.advance()
        status, values, note = self._do(command, fields)
        if not wants_reply:
            return None, note
        head = struct.pack("<BBB", 0x02, command, status)
        if status != 0:
            return head, note
        return head + struct.pack(reply, *values), note

    def _do(
        self, command: int, fields: tuple[Any, ...]
    ) -> tuple[int, tuple[Any, ...], dict[str, Any] | None]:
        if command == 0x04:
            port, power, mode, regulation, turn_ratio, run_state, limit = fields
            if not (port <= 2 or port == 0xFF) or not -100 <= power <= 100:
                return BAD_PORT, (), None
            for i in range(3) if port == 0xFF else (port,):
                motor = self.motors[i]
                motor.power, motor.mode, motor.regulation = power, mode, regulation
                motor.turn_ratio, motor.run_state, motor.limit = turn_ratio, run_state, limit
                motor.tacho = 0.0
            return (
                0,
                (),
                {
                    "event": "motors",
                    "port": port,
                    "power": power,
                    "limit": limit,
                    **self.snapshot(),
                },
            )
        if command == 0x05:
            port, kind, mode = fields
            if port > 3:
                return BAD_PORT, (), None
            self.inputs[port] = (kind, mode)
            return 0, (), None
        if command == 0x06:
            (port,) = fields
            if port > 2:
                return BAD_PORT, (), None
            m = self.motors[port]
            values = (
                port,
                m.power,
                m.mode,
                m.regulation,
                m.turn_ratio,
                m.run_state,
                m.limit,
                int(m.tacho),
                int(m.block),
                int(m.rotation),
            )
            return 0, values, None
        if command == 0x07:
            (port,) = fields
            if port > 3:
                return BAD_PORT, (), None
            kind, mode = self.inputs.get(port, (0, 0))
            sensor = self.config.sensors.get(str(port + 1))  # type: ignore[call-overload]
            scaled = {"light": self.light(), "sound": 5, "touch": 0}.get(sensor or "", 0)
            raw = 1023 - scaled * 10
            note = (
                {"event": "light", "scaled": scaled, **self.snapshot()}
                if sensor == "light"
                else None
            )
            return 0, (port, True, False, kind, mode, raw, raw, scaled, 0), note
        if command == 0x0A:
            port, relative = fields
            if port > 2:
                return BAD_PORT, (), None
            if relative:
                self.motors[port].block = 0.0
            else:
                self.motors[port].rotation = 0.0
            return 0, (), None
        if command == 0x0B:
            return 0, (int(self.millivolts),), None
        return 0, (SLEEP_LIMIT_MS,), None  # 0x0D KEEPALIVE

    def snapshot(self) -> dict[str, Any]:
        return {
            "pose": [round(self.x, 4), round(self.y, 4), round(math.degrees(self.heading), 2)],
            "powers": [m.power if m.rate(self.speedup) else 0 for m in self.motors],
        }


class StandIn:
    """The stand-in's server: one link at a time, as a brick's Bluetooth."""

    def __init__(
        self,
        brick: SimBrick,
        host: str,
        port: int,
        *,
        silent_after: float | None = None,
        log: IO[str] | None = None,
    ) -> None:
        self.brick = brick
        self.silent_at = None if silent_after is None else time.monotonic() + silent_after
        self.log = log
        self.lock = threading.Lock()
        self.server = socket.create_server((host, port), reuse_port=False)
        self.stopping = threading.Event()

    def serve_forever(self) -> None:
        self.server.settimeout(0.5)
        while not self.stopping.is_set():
            try:
                conn, _ = self.server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            with conn:
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self._serve(conn)

    def _serve(self, conn: socket.socket) -> None:
        conn.settimeout(0.5)
        buffer = b""
        while not self.stopping.is_set():
            try:
                chunk = conn.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                return
            if not chunk:
                return
            buffer += chunk
            while len(buffer) >= 2:
                (length,) = struct.unpack_from("<H", buffer)
                if len(buffer) < 2 + length:
                    break
                telegram, buffer = buffer[2 : 2 + length], buffer[2 + length :]
                if self.silent_at is not None and time.monotonic() >= self.silent_at:
                    continue  # the brick has gone silent: it hears, it does not answer
                with self.lock:
                    reply, note = self.brick.answer(telegram)
                if note is not None and self.log is not None:
                    self.log.write(json.dumps({"at": time.time(), **note}) + "\n")
                    self.log.flush()
                if reply is not None:
                    try:
                        conn.sendall(struct.pack("<H", len(reply)) + reply)
                    except OSError:
                        return

    def close(self) -> None:
        self.stopping.set()
        self.server.close()


# -- the command ---------------------------------------------------------------------------


def add_standin_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--bricks", required=True, metavar="FILE", help="the gateway's bricks file")
    parser.add_argument("--robot", required=True, metavar="ID", help="the brick to play")
    parser.add_argument(
        "--speedup", type=float, default=1.0, help="brick time per wall second (default 1)"
    )
    parser.add_argument(
        "--battery-mv",
        type=float,
        metavar="MV",
        help="the battery's voltage at start, millivolts (default: 8600 for six AA cells, "
        "8000 for the rechargeable pack)",
    )
    parser.add_argument(
        "--stall",
        action="append",
        default=[],
        choices=("A", "B", "C"),
        help="a motor that never turns (repeat for more)",
    )
    parser.add_argument(
        "--silent-after",
        type=float,
        metavar="SECONDS",
        help="stop answering after this many seconds",
    )
    parser.add_argument(
        "--obstacle",
        action="append",
        default=[],
        metavar="X,Y[,R]",
        help="a red obstacle at X,Y (metres), radius R (default 0.1); repeat",
    )
    parser.add_argument(
        "--log", metavar="FILE", help="write motor commands and light reads as JSON lines"
    )
    parser.add_argument(
        "--log-level", default="warning", choices=("debug", "info", "warning", "error")
    )


def obstacle(text: str) -> tuple[float, float, float]:
    try:
        numbers = [float(part) for part in text.split(",")]
    except ValueError:
        numbers = []
    if len(numbers) not in (2, 3) or not all(math.isfinite(n) for n in numbers):
        raise InvalidInput(f"--obstacle {text!r} is not X,Y or X,Y,R in metres.", "--obstacle")
    x, y, r = (*numbers, 0.1) if len(numbers) == 2 else numbers
    if not r > 0:
        raise InvalidInput(f"--obstacle {text!r}: the radius must be more than 0.", "--obstacle")
    return x, y, r


def standin_command(args: argparse.Namespace) -> int:
    bricks = load_bricks(args.bricks)
    config = bricks.robots.get(args.robot)
    if config is None:
        raise InvalidInput(
            f"--robot {args.robot!r} is not in {args.bricks} "
            f"(it has {', '.join(sorted(bricks.robots))}).",
            "--robot",
        )
    if config.reach.tcp is None:
        raise InvalidInput(
            f"robot {args.robot} is reached over Bluetooth in {args.bricks}; a stand-in brick "
            "needs reach.tcp (host:port).",
            "--robot",
        )
    if not 0 < args.speedup <= 1000:
        raise InvalidInput(f"--speedup must be more than 0 and at most 1000, not {args.speedup}.")
    if args.battery_mv is None:
        args.battery_mv = 8600.0 if config.battery == "aa" else 8000.0
    if not 0 <= args.battery_mv <= 10_000:
        raise InvalidInput(f"--battery-mv must be 0 to 10000, not {args.battery_mv}.")
    if args.silent_after is not None and not args.silent_after >= 0:
        raise InvalidInput(f"--silent-after must be 0 or more, not {args.silent_after}.")
    world = World([obstacle(text) for text in args.obstacle])
    host, port = config.reach.tcp_address()
    log = open(args.log, "a", encoding="utf-8") if args.log else None  # noqa: SIM115
    brick = SimBrick(
        config, world, speedup=args.speedup, millivolts=args.battery_mv, stalled=tuple(args.stall)
    )
    try:
        server = StandIn(brick, host, port, silent_after=args.silent_after, log=log)
    except OSError as error:
        raise Unavailable(f"cannot listen on {host}:{port}: {error.strerror or error}.") from None
    print(
        f"stand-in brick {args.robot} on tcp {host}:{port}; Ctrl-C stops",
        file=sys.stderr,
        flush=True,
    )
    signal.signal(signal.SIGTERM, lambda *_: server.close())
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.close()
        if log is not None:
            log.close()
    return 0

