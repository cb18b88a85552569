"""The ROS 2 gateway: Nav2 robots, each on its own Zenoh session, robots of a cloud.

::

    each robot's router or bridge (its own session)     gateway          the cloud's router
    /tf, battery_state, navigate_to_pose feedback,  ->  a RosRobot each  ->  fleets/<name>/states
      status, liveliness tokens
    send_goal, get_result (held), cancel_goal       <-  assign, cancel   <-  robots/*/cmd

A robot joins once it has a pose and a battery, and is idle once its action
server is visible. An assign is acknowledged at once (within the IaaS's
deadline) and its goal sent right after, from the publishing loop; a cancel
sends ``cancel_goal`` for that goal alone and reports the robot idle at once.
States go out when the status or the task's phase changes and otherwise once
a second: feedback at 100 Hz reaches the cloud as at most one state a second.

Callbacks come on Zenoh's threads (each robot's session, the cloud's
commands); one condition guards the robots, and nothing is sent while it is
held.
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from collections.abc import Callable

from robocloud.fleet.messages import Ack, Assign, Cancel, State
from robocloud.gateways.ros2.link import Change, RobotLink
from robocloud.gateways.ros2.robot import RosRobot
from robocloud.gateways.ros2.robots_file import RobotsFile
from robocloud.gateways.zenoh_side import CommandHandler, RobotSide

log = logging.getLogger(__name__)

TICK = 0.05  # seconds between two looks at what to send and publish
UNLISTED_AFTER = 10.0  # seconds before a robot without a pose or a battery is logged
POLL_EVERY = 0.1  # seconds between two reads of the robots' fast topics (link.RINGS)
PUBLISH_EVERY = 1.0  # seconds: each robot's state at least this often, progress at most


class Ros2Gateway:
    """The robots of ``robots`` as robots of the cloud of ``side``.

    ``side`` makes the cloud's side from the gateway's command handler (a
    ``ZenohFleet`` on a client session of the cloud, in ``command.run_gateway``).
    """

    def __init__(
        self,
        side: Callable[[CommandHandler], RobotSide],
        robots: RobotsFile,
        *,
        link: Callable[..., RobotLink] = RobotLink,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
    ) -> None:
        self.robots_file = robots
        self.clock, self.wall = clock, wall
        self._changed = threading.Condition()
        self._robots = {rid: RosRobot(rid, entry) for rid, entry in robots.robots.items()}
        self._links = {rid: link(rid, entry, self._apply) for rid, entry in robots.robots.items()}
        self._outbox: list[Callable[[], None]] = []  # requests to the robots, sent by the loop
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._started = clock()
        self._told: dict[str, float] = {}  # robot -> when to log again that it is not listed
        self.side = side(self._on_command)
        self.cloud = self.side.cloud

    # -- life cycle ----------------------------------------------------------------

    def start(self) -> None:
        for link in self._links.values():
            link.start()
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="ros2-publish", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
            self._thread = None
        for link in self._links.values():
            link.close()
        self.side.close()

    def __enter__(self) -> Ros2Gateway:
        self.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self.stop()

    def robot(self, robot_id: str) -> RosRobot:
        """The robot (for tests: read it under ``lock``)."""
        return self._robots[robot_id]

    @property
    def lock(self) -> threading.Condition:
        return self._changed

    # -- the robots' side --------------------------------------------------------------

    def _apply(self, robot_id: str, change: Change) -> None:
        with self._changed:
            robot = self._robots[robot_id]
            change(robot, self.clock())
            notes, robot.notes = robot.notes, []
            events, robot.events = robot.events, []
        for event in events:
            log.info("%s", event)
        for note in notes:
            log.warning("%s", note)

    # -- the cloud's commands ----------------------------------------------------------

    def _on_command(self, robot_id: str, command: Assign | Cancel) -> Ack:
        rid = command.request_id
        link = self._links.get(robot_id)
        with self._changed:
            robot = self._robots.get(robot_id)
            if robot is None or link is None:
                return Ack.refuse(robot_id, rid, f"the gateway has no robot {robot_id}.")
            now = self.clock()
            if isinstance(command, Cancel):
                refusal, job = robot.cancel(rid)
                if refusal is not None:
                    return Ack.refuse(robot_id, rid, refusal)
                if job is not None and job.sent:
                    goal = job.goal_id
                    self._outbox.append(lambda: link.cancel_goal(goal))
                    log.info("%s cancel: cancel_goal for %s (request %s)", robot_id,
                             goal.hex(), rid)  # fmt: skip
                self._changed.notify_all()
                return Ack(ok=True, robot=robot_id, request_id=rid)
            refusal = robot.refuse(command, self.robots_file.min_battery, now)
            if refusal is not None:
                return Ack.refuse(robot_id, rid, refusal)
            if robot.job is not None:  # the same request again: it is on it
                return Ack(ok=True, robot=robot_id, request_id=rid)
            job = robot.take(command, now)
            job.sent = True
            goal, (x, y) = job.goal_id, job.goal_map
            self._outbox.append(lambda: link.send_goal(goal, x, y))
            log.info("%s assign: goal %s to (%.2f, %.2f) in %s for request %s", robot_id,
                     goal.hex(), x, y, robot.entry.map_frame, rid)  # fmt: skip
            self._changed.notify_all()
        return Ack(ok=True, robot=robot_id, request_id=rid)

    # -- out: requests and states ---------------------------------------------------------

    def _loop(self) -> None:
        polled = -1.0
        while not self._stop.is_set():
            if self.clock() - polled >= POLL_EVERY:
                polled = self.clock()
                for link in self._links.values():
                    try:
                        link.poll()
                    except Exception:
                        log.exception("reading robot %s failed", link.robot_id)
            with self._changed:
                self._changed.wait_for(lambda: bool(self._outbox) or self._stop.is_set(), TICK)
                outbox, self._outbox = self._outbox, []
            for send in outbox:  # after the command handler returned (its ack may still be going)
                try:
                    send()
                except Exception:
                    log.exception("a request to a robot failed")
            try:
                self.publish_due()
            except Exception:
                log.exception("publishing the robots' states failed")

    def publish_due(self) -> None:
        """Publish each robot whose state changed or is due."""
        now, wall = self.clock(), self.wall()
        states: list[State] = []
        with self._changed:
            for rid, robot in self._robots.items():
                robot.tick(now)
                for goal in robot.cancels:
                    self._outbox.append(functools.partial(self._links[rid].cancel_goal, goal))
                robot.cancels = []
                if not robot.dirty and now - robot.published_at < PUBLISH_EVERY:
                    continue
                state = robot.state(self.cloud, self.robots_file.cost_per_m(rid), now, wall)
                if state is None:
                    if now - self._started > UNLISTED_AFTER and now >= self._told.get(rid, 0):
                        self._told[rid] = now + UNLISTED_AFTER * 6
                        log.warning("robot %s is not listed: %s", rid, robot.missing())
                    continue
                # A change goes out at once; otherwise on a one-second grid, so a late
                # loop neither lowers the rate below one a second nor raises it above.
                due = robot.published_at + PUBLISH_EVERY
                regular = not robot.dirty and now - due < PUBLISH_EVERY
                robot.published_at = due if regular else now
                robot.dirty = False
                states.append(state)
            notes = [n for r in self._robots.values() for n in r.notes]
            for r in self._robots.values():
                r.notes = []
        for note in notes:
            log.warning("%s", note)
        for state in states:
            if not self.side.has(state.id):
                self.side.add(state.id)
                log.info("robot %s joined %s (%s)", state.id, self.cloud, state.status)
            self.side.publish(state)
