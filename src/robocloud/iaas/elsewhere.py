"""A request asked for at the wrong cloud: the 404 says which cloud holds it.

Each request lives at the cloud whose IaaS received it (its store, its
actor); its id does not say which (``req-`` and 12 random letters). Serving
it through another cloud would mean forwarding the application's key to that
cloud's API; instead, a cloud that does not hold a request asks the other
live clouds the overlay's ``status`` question (open to every member, answered
from the holder's store) and its 404 names the cloud that knows it, with that
cloud's API when it says it. A cloud that does not answer is named as one
that may hold it. The holder is named by its own answer: a member of the
federation (docs/security.md), like every cloud that lends robots.

Bounds: at most ``MAX_LOOKUPS`` lookups run at once (more get the plain 404
at once), each waits for the overlay's call timeout, and the last
``REMEMBERED`` holders found are kept, so a client polling the wrong cloud
asks the federation once.
"""

from __future__ import annotations

import asyncio
from collections import OrderedDict
from collections.abc import Awaitable
from typing import TypeVar

from robocloud.errors import NotFound
from robocloud.federation.messages import StatusQuery
from robocloud.federation.overlay import Overlay, Unreachable
from robocloud.iaas.service import REQUEST_ID

MAX_LOOKUPS = 4
REMEMBERED = 1000

T = TypeVar("T")


class Elsewhere:
    def __init__(self, overlay: Overlay | None) -> None:
        self._overlay = overlay
        self._running = 0
        # request id -> (the cloud that holds it, its API)
        self._holders: OrderedDict[str, tuple[str, str | None]] = OrderedDict()

    async def here(self, call: Awaitable[T], request_id: str) -> T:
        """``call``'s result; its ``NotFound`` says where the request is, if elsewhere."""
        try:
            return await call
        except NotFound as error:
            sentence = await self.sentence(request_id)
            if sentence is None:
                raise
            raise NotFound(sentence, request_id) from error

    async def sentence(self, request_id: str) -> str | None:
        """The 404's sentence when another cloud holds (or may hold) the request."""
        overlay = self._overlay
        if overlay is None or not REQUEST_ID.fullmatch(request_id):
            return None
        found = self._holders.get(request_id)
        silent: list[str] = []
        if found is None:
            if self._running >= MAX_LOOKUPS:
                return None
            self._running += 1
            try:
                holder, silent = await self._ask(overlay, request_id)
                if holder is not None:
                    found = (holder, await self._api_of(overlay, holder))
            finally:
                self._running -= 1
        here = overlay.cloud
        if found is not None:
            holder, api = found
            self._remember(request_id, found)
            where = f" (its API: {api})" if api else ""
            return (
                f"there is no request {request_id!r} at {here}: it is held by {holder}{where}, "
                "the cloud whose IaaS received it; ask there, with a key it accepts."
            )
        if silent:
            return (
                f"there is no request {request_id!r} at {here}, and no cloud that answered "
                f"knows it; {', '.join(silent)} did not answer: it may be there."
            )
        return None

    async def _ask(self, overlay: Overlay, request_id: str) -> tuple[str | None, list[str]]:
        others = [c for c in overlay.clouds() if c != overlay.cloud]
        query = StatusQuery(home=overlay.cloud, request_ids=[request_id])

        def ask(cloud: str) -> bool | None:
            try:
                reply = overlay.status(cloud, query)
            except Unreachable:
                return None
            return any(s.request_id == request_id and s.known for s in reply.requests)

        answers = await asyncio.gather(*(asyncio.to_thread(ask, c) for c in others))
        holder = next((c for c, known in zip(others, answers, strict=True) if known), None)
        silent = [c for c, known in zip(others, answers, strict=True) if known is None]
        return holder, silent

    @staticmethod
    async def _api_of(overlay: Overlay, cloud: str) -> str | None:
        infos = await asyncio.to_thread(overlay.infos)
        return next((i.api for i in infos if i.cloud == cloud), None)

    def _remember(self, request_id: str, found: tuple[str, str | None]) -> None:
        self._holders[request_id] = found
        self._holders.move_to_end(request_id)
        while len(self._holders) > REMEMBERED:
            self._holders.popitem(last=False)
