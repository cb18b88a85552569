"""``GET /v1/robots`` in pages: filters, an opaque cursor, a ``Link`` to the next page, an ETag.

The body stays what it always was, a JSON list of robots (``RobotPublic``), so
clients that read a list keep working; what is new travels in headers:

- ``Link: </v1/robots?...&cursor=...>; rel="next"`` while more robots follow
  (RFC 8288, as GitHub's API does; httpx and requests parse it as
  ``response.links["next"]``). The cursor is opaque: the position after the
  last robot of the page (robots are listed by cloud, then id), so a walk sees
  every robot that is there all along exactly once, even while others come
  and go.
- ``X-Total-Count``: how many robots match the filters, over every page.
- ``ETag`` (weak): a digest of the page without ``seen_ago`` (which changes
  every instant). A client that sends it back in ``If-None-Match`` gets
  ``304 Not Modified`` and no body while no robot of the page changed its
  status, position, battery, capabilities, request or progress.

Robots are filtered before anything is built for them, and the page alone is
turned into JSON (plain values, encoded by msgspec).
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import json
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlencode

import msgspec

from robocloud.domain import Robot
from robocloud.errors import InvalidInput, explained
from robocloud.iaas.presenters import (
    refused_robot_json,
    remote_robot_json,
    robot_json,
    shown_status,
)
from robocloud.iaas.routes import SetAside

DEFAULT_LIMIT = 1000  # robots a page when the client does not say
MAX_LIMIT = 10_000  # the most a client may ask for (about 2.8 MB of JSON, 0.2 MB gzipped)
# A page stops at the robot that takes its JSON past this many bytes (a robot
# may carry 100 capabilities of 128-character names: about 30 KB; 10,000 of
# them made a 300 MB page); ``Link`` then leads on from there. Ordinary
# robots (about 300 bytes) never reach it below MAX_LIMIT.
PAGE_BYTES = 4 * 1024 * 1024
# Robots whose JSON the listing keeps between pages (about 0.6 KB each): a
# fleet at rest of up to this many costs a look-up a robot; a larger one is
# encoded again page by page instead of kept whole.
KEPT = 20_000
CURSOR_PATTERN = explained(
    r"^[A-Za-z0-9_-]{1,700}$", "the cursor of the previous page (letters, digits, - and _)"
)

Key = tuple[str, str]  # (cloud, robot id): the order of the list


@dataclass(frozen=True)
class RobotFilter:
    """What ``status``, ``capability`` (every one given) and ``cloud`` ask for."""

    status: str | None = None
    capabilities: tuple[str, ...] = ()
    cloud: str | None = None

    def keeps(self, cloud: str, status: str, capabilities: Iterable[str]) -> bool:
        if self.cloud is not None and cloud != self.cloud:
            return False
        if self.status is not None and status != self.status:
            return False
        return not self.capabilities or set(self.capabilities) <= set(capabilities)


@dataclass
class Page:
    robots: list[bytes]  # each robot's JSON
    steady: list[bytes]  # the same without seen_ago (what the ETag covers)
    total: int  # robots matching the filters, over every page
    next: Key | None  # the position after this page, if more follow

    def body(self) -> bytes:
        return b"[" + b",".join(self.robots) + b"]"


class RobotJson:
    """Each robot's JSON but ``seen_ago``, kept while the link hands out the same state.

    A fleet at rest costs a dictionary look-up a robot; a robot whose state
    changed (the link makes new objects for new states) is encoded again.
    """

    def __init__(self) -> None:
        self._kept: dict[
            str, tuple[Robot, Any, str | None, SetAside | None, bool, str | None, bytes]
        ] = {}

    def steady(
        self,
        robot: Robot,
        state: Any,
        request: str | None,
        aside: SetAside | None = None,
        owned: bool = False,
        refused: str | None = None,
    ) -> bytes:
        """The robot's JSON; ``owned``: the asker owns ``request`` (it sees it and the progress)."""
        kept = self._kept.get(robot.id)
        if (
            kept is not None
            and kept[0] is robot
            and kept[1] is state
            and kept[2] == request
            and kept[3] is aside
            and kept[4] is owned
            and kept[5] == refused
        ):
            return kept[6]
        data = robot_json(robot, state, None, request, aside, owned, refused)
        del data["seen_ago"]
        raw = msgspec.json.encode(data)
        self._kept[robot.id] = (robot, state, request, aside, owned, refused, raw)
        return raw

    def __len__(self) -> int:
        return len(self._kept)

    def prune(self, present: int) -> None:
        """Forget robots no longer listed once the cache is twice the fleet, and every robot
        once it holds more than ``KEPT``: a walk of a large fleet keeps one page's worth, not
        the fleet's (issue 25: 100,000 robots' JSON stayed after a full listing)."""
        if len(self._kept) > min(2 * present + 100, KEPT):
            self._kept.clear()


def encode_cursor(key: Key) -> str:
    raw = json.dumps(list(key), separators=(",", ":")).encode()
    return base64.urlsafe_b64encode(raw).decode().rstrip("=")


def decode_cursor(cursor: str) -> Key:
    """The position a cursor of ``encode_cursor`` stands for, or a 422 sentence."""
    try:
        raw = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4))
        key = json.loads(raw)
    except (binascii.Error, ValueError):
        key = None
    if not (isinstance(key, list) and len(key) == 2 and all(isinstance(k, str) for k in key)):
        raise InvalidInput(
            "cursor: is not a cursor this API gave; take it from the Link header of the "
            "previous page, or leave it out to start from the first robot.",
            "cursor",
        )
    return key[0], key[1]


def local_rows(
    robots: Sequence[Robot], held: dict[str, str], wanted: RobotFilter
) -> list[tuple[Key, Robot]]:
    """This cloud's robots that match, in list order, nothing built for them yet."""
    return [
        ((robot.cloud, robot.id), robot)
        for robot in robots
        if wanted.keeps(robot.cloud, shown_status(robot.status, held.get(robot.id)),
                        robot.capabilities)
    ]


def refused_rows(
    cloud: str, refused: dict[str, str], known: Iterable[str], wanted: RobotFilter
) -> list[tuple[Key, dict[str, Any]]]:
    """Robots of this cloud none of whose states was accepted: listed offline with the reason.

    At most ``MAX_TRACKED`` of them (``robocloud.fleet.state_errors``), one reason each.
    """
    heard = set(known)
    return [
        ((cloud, robot), refused_robot_json(robot, cloud, why))
        for robot, why in refused.items()
        if robot not in heard and wanted.keeps(cloud, "offline", ())
    ]


def remote_rows(
    fleets: Iterable[Sequence[dict[str, Any]]],
    wanted: RobotFilter,
    exclude_cloud: str,
    owns: Callable[[str], bool] = lambda request: False,
) -> list[tuple[Key, dict[str, Any]]]:
    """Other clouds' robots (as their homes sent them) that match, as wire values.

    ``owns``: whether the asking application owns a request (it sees its id and progress).
    """
    rows = []
    for robots in fleets:
        for data in robots:
            try:
                robot = remote_robot_json(data, owns)
            except (KeyError, TypeError, ValueError, AttributeError):
                continue  # a home that sent something else: left out, not a 500
            if robot["cloud"] != exclude_cloud and wanted.keeps(
                robot["cloud"], robot["status"], robot["capabilities"]
            ):
                rows.append(((robot["cloud"], robot["id"]), robot))
    return rows


def page_of(
    rows: list[tuple[Key, Any]], after: Key | None, limit: int
) -> tuple[list[tuple[Key, Any]], int, Key | None]:
    """The rows after the cursor, at most ``limit``; the total; the next cursor."""
    rows.sort(key=lambda row: row[0])
    total = len(rows)
    start = 0
    if after is not None:
        # Binary search: the first row past the cursor.
        lo, hi = 0, total
        while lo < hi:
            mid = (lo + hi) // 2
            if rows[mid][0] <= after:
                lo = mid + 1
            else:
                hi = mid
        start = lo
    chosen = rows[start : start + limit]
    more = start + limit < total
    return chosen, total, (chosen[-1][0] if more and chosen else None)


def build_page(
    local: list[tuple[Key, Robot]],
    remote: list[tuple[Key, dict[str, Any]]],
    after: Key | None,
    limit: int,
    states: dict[str, Any],
    ages: dict[str, float],
    held: dict[str, str],
    cache: RobotJson,
    aside: Callable[[str], SetAside | None] = lambda robot: None,
    owns: Callable[[str], bool] = lambda request: False,
    budget: int = PAGE_BYTES,
    refused: dict[str, str] | None = None,
) -> Page:
    """The page after ``after``: at most ``limit`` robots, and it stops at the first that
    takes it past ``budget`` bytes (one robot at least); a robot's request and progress
    only where the asker ``owns`` it."""
    rows: list[tuple[Key, Any]] = [*local, *remote]
    chosen, total, next_key = page_of(rows, after, limit)
    robots, steady = [], []
    size = 0
    for index, (key, item) in enumerate(chosen):
        if isinstance(item, dict):
            raw = msgspec.json.encode(item)  # seen_ago is null: nothing to leave out
            robots.append(raw)
            steady.append(raw)
        else:
            request = held.get(item.id)
            owned = request is not None and owns(request)
            raw = cache.steady(item, states.get(item.id), request, aside(item.id), owned,
                               refused.get(item.id) if refused else None)
            age = ages.get(item.id)
            seen = msgspec.json.encode(round(age, 3)) if age is not None else b"null"
            robots.append(raw[:-1] + b',"seen_ago":' + seen + b"}")
            steady.append(raw)
        size += len(robots[-1]) + 1
        if size >= budget and index + 1 < len(chosen):
            next_key = key  # the rest of the page is the next page's
            break
    cache.prune(len(local))
    return Page(robots, steady, total, next_key)


def etag_of(page: Page) -> str:
    """A weak validator of what the page says, but for ``seen_ago``."""
    digest = hashlib.blake2b(b"\n".join(page.steady), digest_size=12)
    if page.next is not None:
        digest.update(b"\0" + encode_cursor(page.next).encode())
    return f'W/"{digest.hexdigest()}"'


def matches(if_none_match: str | None, etag: str) -> bool:
    """Whether ``If-None-Match`` names the ETag (weak comparison, RFC 9110)."""
    if not if_none_match:
        return False
    if if_none_match.strip() == "*":
        return True
    bare = etag.removeprefix("W/")
    return any(tag.strip().removeprefix("W/") == bare for tag in if_none_match.split(","))


def next_link(path: str, query: list[tuple[str, str]], next_key: Key) -> str:
    """The ``Link`` header to the next page: the same query, the cursor moved on."""
    kept = [(k, v) for k, v in query if k != "cursor"]
    kept.append(("cursor", encode_cursor(next_key)))
    return f'<{path}?{urlencode(kept)}>; rel="next"'
