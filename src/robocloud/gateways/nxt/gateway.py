"""The NXT gateway: the bricks of a bricks file, robots of a cloud on Zenoh.

::

    bricks (RFCOMM or TCP)               gateway            IaaS (robocloud/<cloud>/robots/...)
    battery, rotation counts, sensors -> a Brick each  ->  <id>/state
    SETOUTPUTSTATE (movements, brake) <- a driver each <-  <id>/cmd (assign, cancel)

Each brick is the robot of its id in the file. It appears once the brick has
answered its first battery level, publishes a state at least twice a second
and at once on a change of its status or its task's phase. An assign is
acknowledged at once (the driver starts the movement within a cycle); a
cancel is acknowledged once the brick is told to brake, which the driver does
on its next cycle (tens of milliseconds).

The Zenoh side is every gateway's (``gateways/zenoh_side.py``),
which knows nothing of VDA 5050: the keys of a robot per brick, or with
``--gateway-name`` those of a fleet gateway.

Threads: a driver per brick (``driver.py``), the publisher, and Zenoh's
(commands). One condition guards every ``Brick``; nothing is sent while it is
held. Each thread is started by ``start`` and joined by ``stop``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from robocloud.fleet.messages import Ack, Assign, Cancel, State
from robocloud.gateways.nxt.brick import Brick
from robocloud.gateways.nxt.bricks import BrickConfig, BricksFile
from robocloud.gateways.nxt.driver import REPLY_TIMEOUT, BrickDriver
from robocloud.gateways.nxt.transport import Link, connect_rfcomm, connect_tcp
from robocloud.gateways.zenoh_side import CommandHandler, RobotSide

log = logging.getLogger(__name__)

TICK = 0.05  # seconds between two looks at what to publish
PUBLISH_EVERY = 0.5  # seconds: each robot's state at least this often

LinkOpener = Callable[[BrickConfig], Link]


def open_link(config: BrickConfig) -> Link:
    """The link to a brick: RFCOMM to its Bluetooth address, or TCP to a stand-in."""
    reach = config.reach
    if reach.bluetooth is not None:
        return connect_rfcomm(reach.bluetooth, REPLY_TIMEOUT)
    host, port = reach.tcp_address()
    return connect_tcp(host, port, REPLY_TIMEOUT)


class NxtGateway:
    """The bricks of ``bricks`` as robots; ``robots`` makes the Zenoh side from the handler."""

    def __init__(
        self,
        robots: Callable[[CommandHandler], RobotSide],
        bricks: BricksFile,
        *,
        opener: LinkOpener = open_link,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
    ) -> None:
        self.robots = robots(self._on_command)
        self.cloud = self.robots.cloud
        self.clock, self.wall = clock, wall
        self._changed = threading.Condition()
        self._stop = threading.Event()
        self.bricks = {
            robot: Brick(robot, config, bricks.min_battery)
            for robot, config in bricks.robots.items()
        }
        self.drivers = [
            BrickDriver(
                brick,
                self._changed,
                lambda config=brick.config: opener(config),  # type: ignore[misc]
                self._stop,
                clock,
            )
            for brick in self.bricks.values()
        ]
        self._publisher = threading.Thread(target=self._loop, name="nxt-publish", daemon=True)

    def start(self) -> None:
        for driver in self.drivers:
            driver.start()
        self._publisher.start()

    def stop(self) -> None:
        self._stop.set()
        with self._changed:
            self._changed.notify_all()
        for driver in self.drivers:
            driver.join(5)
        self._publisher.join(5)
        self.robots.close()

    def __enter__(self) -> NxtGateway:
        self.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self.stop()

    # -- Zenoh in: commands ------------------------------------------------------------

    def _on_command(self, robot: str, command: Assign | Cancel) -> Ack:
        rid = command.request_id
        with self._changed:
            brick = self.bricks.get(robot)
            if brick is None:
                return Ack.refuse(robot, rid, f"the gateway has no brick {robot}.")
            if isinstance(command, Cancel):
                refusal = brick.cancel(rid)
            else:
                refusal = brick.refuse(command, self.clock())
                if refusal is None:
                    brick.take(command)
            self._changed.notify_all()
        if refusal is not None:
            return Ack.refuse(robot, rid, refusal)
        log.info("%s %s: %s", robot, command.type, rid)
        return Ack(ok=True, robot=robot, request_id=rid)

    # -- Zenoh out: states ---------------------------------------------------------------

    def _loop(self) -> None:
        while not self._stop.wait(TICK):
            try:
                self.publish_due()
            except Exception:
                log.exception("publishing the bricks' states failed")

    def publish_due(self) -> None:
        now, wall = self.clock(), self.wall()
        states: list[State] = []
        notes: list[str] = []
        with self._changed:
            for brick in self.bricks.values():
                notes += brick.notes
                brick.notes = []
                if not brick.dirty and now - brick.published_at < PUBLISH_EVERY:
                    continue
                state = brick.state(self.cloud, now, wall)
                if state is None:
                    continue
                brick.dirty, brick.published_at = False, now
                states.append(state)
        for note in notes:
            log.warning("%s", note)
        for state in states:
            if not self.robots.has(state.id):
                self.robots.add(state.id)
                log.info("brick %s is robot %s of %s", state.id, state.id, self.cloud)
            self.robots.publish(state)
