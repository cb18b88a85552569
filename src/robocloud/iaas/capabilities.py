"""A task naming a capability no robot of the federation has announced is refused at POST.

Without this it was accepted (202) and then rejected with a reason that read
like a shortage ("needs 1 robot, but only 0 ... bring it"; issue 26), though
no number of idle robots would ever have served it.

The names known are this cloud's robots' (``Home.announced``, learned from
the link) and the other clouds', from their ``CloudInfo`` (each says every
name its robots have announced since its IaaS started). Only a name not known
yet costs anything: the link's robots are read again and, at most once a
second (``ASK_EVERY_S``), every live cloud is asked; a name still unknown is
refused with a sentence naming it (unless nothing at all has been heard yet:
a cloud just started cannot tell). A cloud that does not answer cannot tell
its names: they count once it answers. Once a catalogue is full
(``robocloud.federation.capabilities.MAX_NAMES``) nothing is refused for
being unknown.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

from robocloud.domain import Robot, Task
from robocloud.errors import InvalidInput
from robocloud.federation.capabilities import Announced
from robocloud.federation.overlay import Overlay

ASK_EVERY_S = 1.0
SHOWN = 20  # known names a refusal lists


class KnownCapabilities:
    def __init__(
        self,
        own: Announced,
        robots: Callable[[], list[Robot]],
        overlay: Overlay | None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._own = own
        self._robots = robots
        self._overlay = overlay
        self._clock = clock
        self._others = Announced()
        self._asked_at: float | None = None
        self._asking = asyncio.Lock()

    def _known(self, name: str) -> bool:
        return name in self._own or name in self._others

    def _unknown(self, task: Task) -> list[str]:
        if self._own.full or self._others.full:
            return []
        return [n for n in (*task.sensing, *task.actuating) if not self._known(n)]

    async def check(self, task: Task) -> None:
        """Raise ``InvalidInput`` naming the first capability no robot has announced."""
        if not self._unknown(task):
            return
        self._own.learn_robots(self._robots())
        if self._unknown(task) and self._overlay is not None:
            async with self._asking:
                now = self._clock()
                if self._unknown(task) and (
                    self._asked_at is None or now - self._asked_at >= ASK_EVERY_S
                ):
                    self._asked_at = now
                    for info in await asyncio.to_thread(self._overlay.infos):
                        if info.cloud != self._overlay.cloud:
                            self._others.learn(info.capabilities)
        unknown = self._unknown(task)
        known = sorted({*self._own.names(), *self._others.names()})
        if not unknown or not known:
            return  # nothing heard yet (a cloud just started): the selection decides
        name = unknown[0]
        kind = "sensing" if name in task.sensing else "actuating"
        listed = ", ".join(known[:SHOWN]) + (", ..." if len(known) > SHOWN else "")
        where = "the federation" if self._overlay is not None else "this cloud"
        raise InvalidInput(
            f"{kind}.{name}: no robot of {where} has announced the capability {name!r}, so "
            f"none could serve this task; the capabilities announced are {listed}.",
            field=f"{kind}.{name}",
        )
