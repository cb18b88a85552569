"""The I/O of one brick: a thread that keeps its link, reads it and tells its motors.

Each cycle, under the gateway's condition only to talk to the ``Brick``:

1. brake every motor when the brick wants it (a cancel, a failure, a search
   that saw its obstacle): one SETOUTPUTSTATE to port 0xFF;
2. read the rotation counts of its motors (GETOUTPUTSTATE each) and, during a
   search, its light sensor (GETINPUTVALUES);
3. start the next movement, if one is due, with the counts just read;
4. now and then read the battery (GETBATTERYLEVEL, with the motors still when
   it can: the voltage sags under load) and keep the brick awake (KEEPALIVE);
5. wait: ``MOVING_EVERY`` while something moves, ``IDLE_EVERY`` otherwise, or
   until a command wakes it.

A reply that does not come within ``REPLY_TIMEOUT`` drops the link; the
driver connects again every ``RETRY_EVERY`` seconds, and the brick counts its
silence (``Brick.on_silence``). On every new connection the sensors are set up
(SETINPUTMODE) and the motors braked, whatever they were told before.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from robocloud.gateways.nxt import telegrams as t
from robocloud.gateways.nxt.brick import Brick, Movement
from robocloud.gateways.nxt.transport import Link, LinkDown

log = logging.getLogger(__name__)

REPLY_TIMEOUT = 1.0  # seconds; a Bluetooth round trip of the NXT takes tens of ms
RETRY_EVERY = 1.0  # seconds between two connection attempts
MOVING_EVERY = 0.02  # seconds between two readings while a motor moves
IDLE_EVERY = 0.25  # seconds between two readings otherwise (the brick's liveness)
BATTERY_EVERY = 5.0  # seconds between two battery readings
KEEPALIVE_EVERY = 60.0  # seconds; the brick's sleep timer is minutes

SENSOR_MODES = {
    "light": t.PERCENT_MODE,
    "sound": t.PERCENT_MODE,
    "touch": t.BOOLEAN_MODE,
    "ultrasonic": t.RAW_MODE,
}


class BrickDriver:
    def __init__(
        self,
        brick: Brick,
        changed: threading.Condition,
        connect: Callable[[], Link],
        stopping: threading.Event,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.brick = brick
        self.changed = changed
        self.connect = connect
        self.stopping = stopping
        self.clock = clock
        self.exchanges = 0  # telegrams answered, for the log and benchmarks
        self.thread = threading.Thread(target=self._run, name=f"nxt-{brick.robot_id}", daemon=True)

    def start(self) -> None:
        self.thread.start()

    def join(self, timeout: float) -> None:
        self.thread.join(timeout)

    def _run(self) -> None:
        robot = self.brick.robot_id
        complained: str | None = None
        while not self.stopping.is_set():
            link: Link | None = None
            try:
                link = self.connect()
                self._set_up(link)
                log.info("brick %s answers (%s)", robot, self.brick.config.reach.describe())
                self._serve(link)
            except LinkDown as error:
                log.debug("brick %s: %s", robot, error)
                with self.changed:
                    self.brick.on_silence(self.clock())
                    self.changed.notify_all()
                self.stopping.wait(RETRY_EVERY if link is None else 0.0)
            except t.TelegramError as error:
                if str(error) != complained:  # once, not every second it goes on
                    log.warning("brick %s: %s; connecting again", robot, error)
                    complained = str(error)
                self.stopping.wait(RETRY_EVERY)
            except Exception:  # nothing a brick says stops its driver
                log.exception("the driver of brick %s failed; connecting again", robot)
                self.stopping.wait(RETRY_EVERY)
            finally:
                if link is not None:
                    link.close()

    def _ask(self, link: Link, telegram: bytes) -> bytes:
        reply = link.exchange(telegram)
        self.exchanges += 1
        return reply

    def _set_up(self, link: Link) -> None:
        t.parse_status(self._ask(link, t.stop_outputs()), t.SETOUTPUTSTATE)
        for port, kind in sorted(self.brick.config.sensors.items()):
            telegram = t.set_input_mode(int(port) - 1, t.SENSOR_TYPES[kind], SENSOR_MODES[kind])
            t.parse_status(self._ask(link, telegram), t.SETINPUTMODE)
        millivolts = t.parse_battery_level(self._ask(link, t.get_battery_level()))
        with self.changed:
            self.brick.on_connected(self.clock())
            self.brick.on_battery(millivolts)
            self.changed.notify_all()

    def _serve(self, link: Link) -> None:
        brick = self.brick
        battery_at = keepalive_at = self.clock()
        cycle = 0
        while not self.stopping.is_set():
            with self.changed:
                stop = brick.stop_wanted
                ports = brick.ports_to_read()
                sensor = brick.sensor_to_read()
            cycle += 1
            if cycle % 2:
                # The two wheels are read one after the other; read in turn first, the
                # lag between them (a turn of the brick it did not make) cancels out.
                ports[0], ports[1] = ports[1], ports[0]
            if stop:
                t.parse_status(self._ask(link, t.stop_outputs()), t.SETOUTPUTSTATE)
                with self.changed:
                    brick.stopped()
            states = {
                p: t.parse_output_state(self._ask(link, t.get_output_state(p))) for p in ports
            }
            scaled = None
            if sensor is not None:
                scaled = t.parse_input_values(self._ask(link, t.get_input_values(sensor))).scaled
            now = self.clock()
            with self.changed:
                brick.on_answer(now)
                brick.on_outputs(states, now)
                if sensor is not None and scaled is not None:
                    brick.on_sensor(sensor, scaled, now)
                movement = None if brick.stop_wanted else brick.next_movement(now)
                moving = brick.movement is not None
                self.changed.notify_all()
            if movement is not None:
                self._start(link, movement)
                moving = True
            if not moving and now - battery_at >= BATTERY_EVERY:
                millivolts = t.parse_battery_level(self._ask(link, t.get_battery_level()))
                battery_at = now
                with self.changed:
                    brick.on_battery(millivolts)
            if now - keepalive_at >= KEEPALIVE_EVERY:
                t.parse_keep_alive(self._ask(link, t.keep_alive()))
                keepalive_at = now
            with self.changed:
                if not brick.stop_wanted and not brick.movement_due():
                    self.changed.wait(MOVING_EVERY if moving else IDLE_EVERY)

    def _start(self, link: Link, movement: Movement) -> None:
        # Back to back, only the last one answered: over Bluetooth each answer costs a
        # turn of the link (tens of ms), and wheels started that far apart turn the brick.
        motors = list(movement.motors.items())
        for i, (port, (power, limit)) in enumerate(motors):
            last = i == len(motors) - 1
            telegram = t.set_output_state(port, power, tacho_limit=limit, reply=last)
            if last:
                t.parse_status(self._ask(link, telegram), t.SETOUTPUTSTATE)
            else:
                link.send(telegram)
        with self.changed:
            self.brick.started(movement, self.clock())
