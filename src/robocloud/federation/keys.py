"""The Zenoh keys between clouds: questions anyone may ask, commands that name their sender.

::

    robocloud/<cloud>/<question>               info, idle, fleet, status: open to all members
    robocloud/<home>/from/<origin>/<command>   reserve, confirm, release, dispatch, cancel, loans
    robocloud/federation/clouds/<cloud>/<zid>  liveliness token of a cloud's IaaS: its
                                               Zenoh session id, the only one whose
                                               replies speak for the cloud

A command is sent on a key that names its sender (the origin), and the home
takes the origin from the key, never from the payload. With mutual TLS the
home's router lets each trusted cloud's certificate query only the keys that
name that cloud (``robocloud.federation.security.policy``), so the key is
proof of the sender. Cloud names are single key chunks (``robocloud.fleet.keys``).

Kept free of heavy imports: the command-line parser reads it through the
security flags.
"""

from __future__ import annotations

from robocloud.fleet.keys import ROOT, check_chunk

QUESTIONS = ("info", "idle", "fleet", "status")
COMMANDS = ("reserve", "confirm", "release", "dispatch", "cancel", "loans")
CLOUDS_TOKEN = f"{ROOT}/federation/clouds"
_FROM = "from"


def question(cloud: str, name: str) -> str:
    """``robocloud/<cloud>/<name>``; ``cloud`` may be ``*`` for every cloud."""
    assert name in QUESTIONS, name
    return f"{ROOT}/{cloud if cloud == '*' else check_chunk(cloud, 'cloud')}/{name}"


def command(home: str, origin: str, name: str) -> str:
    """``robocloud/<home>/from/<origin>/<name>``; ``origin`` may be ``*`` (a home's queryable)."""
    assert name in COMMANDS, name
    sender = origin if origin == "*" else check_chunk(origin, "origin")
    return f"{ROOT}/{check_chunk(home, 'cloud')}/{_FROM}/{sender}/{name}"


def sender_of(key: str) -> str | None:
    """The origin named by a command key, None for any other key."""
    parts = key.split("/")
    if len(parts) != 5 or parts[0] != ROOT or parts[2] != _FROM or parts[4] not in COMMANDS:
        return None
    return parts[3] or None


def cloud_token(cloud: str, zid: str) -> str:
    """The presence token of ``cloud``'s IaaS, whose Zenoh session is ``zid``."""
    return f"{CLOUDS_TOKEN}/{check_chunk(cloud, 'cloud')}/{check_chunk(zid, 'session')}"


def all_cloud_tokens() -> str:
    return f"{CLOUDS_TOKEN}/*/*"


def token_owner(key: str) -> tuple[str, str] | None:
    """(cloud, session id) of a presence token's key; None for another key."""
    prefix = f"{CLOUDS_TOKEN}/"
    if not key.startswith(prefix):
        return None
    parts = key[len(prefix) :].split("/")
    if len(parts) != 2 or not all(parts):
        return None
    return parts[0], parts[1]
