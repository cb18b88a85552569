"""The Zenoh key expressions of one cloud's robots.

::

    robocloud/<cloud>/robots/<id>/state   each robot publishes its State (JSON)
    robocloud/<cloud>/robots/<id>/cmd     the IaaS queries it with a Command; the reply is an Ack
    robocloud/<cloud>/robots/<id>/error   the IaaS publishes a StateError for a state it refused
    robocloud/<cloud>/fleets/<gw>/states  a gateway publishes its robots' states in batches
                                          (a JSON array of States)
    robocloud/<cloud>/sim/<pid>           liveliness token of a running fleet simulator
    robocloud/<cloud>/sim/control         queryable of the simulator for fault injection

A cloud name and a robot id are single key chunks: no ``/`` and none of
Zenoh's special characters.
"""

from __future__ import annotations

from robocloud.errors import InvalidInput

ROOT = "robocloud"
# Zenoh reserves these in key expressions (wildcards, selectors, verbatim chunks).
_FORBIDDEN = frozenset("/*$?#")


def check_chunk(value: str, what: str) -> str:
    """``value`` if it can stand as one key chunk, else InvalidInput naming ``what``."""
    if not value or any(ch in _FORBIDDEN for ch in value) or value != value.strip():
        raise InvalidInput(
            f"{what} {value!r} cannot be used in a Zenoh key: it must be non-empty, "
            "without spaces around it and without any of / * $ ? #.",
            field=what,
        )
    return value


def robots_prefix(cloud: str) -> str:
    return f"{ROOT}/{check_chunk(cloud, 'cloud')}/robots"


def state_key(cloud: str, robot_id: str) -> str:
    return f"{robots_prefix(cloud)}/{check_chunk(robot_id, 'robot')}/state"


def cmd_key(cloud: str, robot_id: str) -> str:
    return f"{robots_prefix(cloud)}/{check_chunk(robot_id, 'robot')}/cmd"


def error_key(cloud: str, robot_id: str) -> str:
    return f"{robots_prefix(cloud)}/{check_chunk(robot_id, 'robot')}/error"


def all_states(cloud: str) -> str:
    """Every robot's state key of ``cloud``."""
    return f"{robots_prefix(cloud)}/*/state"


def all_cmds(cloud: str) -> str:
    return f"{robots_prefix(cloud)}/*/cmd"


def fleets_prefix(cloud: str) -> str:
    return f"{ROOT}/{check_chunk(cloud, 'cloud')}/fleets"


def batch_key(cloud: str, gateway: str) -> str:
    """Where a gateway (a process fronting many robots) publishes their states in batches."""
    return f"{fleets_prefix(cloud)}/{check_chunk(gateway, 'gateway')}/states"


def all_batches(cloud: str) -> str:
    """Every gateway's batch key of ``cloud``."""
    return f"{fleets_prefix(cloud)}/*/states"


def gateway_of(key: str) -> str | None:
    """The gateway a batch key names (``robocloud/<cloud>/fleets/<gateway>/states``)."""
    parts = key.split("/")
    if len(parts) == 5 and parts[0] == ROOT and parts[2] == "fleets" and parts[4] == "states":
        return parts[3]
    return None


def robot_of(key: str) -> str | None:
    """The robot id in a ``.../robots/<id>/state``, ``cmd`` or ``error`` key; None for others."""
    parts = key.split("/")
    if len(parts) != 5 or parts[0] != ROOT or parts[2] != "robots":
        return None
    return parts[3]


def sim_token(cloud: str, pid: int) -> str:
    return f"{ROOT}/{check_chunk(cloud, 'cloud')}/sim/{pid}"


def all_sim_tokens(cloud: str) -> str:
    return f"{ROOT}/{check_chunk(cloud, 'cloud')}/sim/*"


def sim_control(cloud: str) -> str:
    return f"{ROOT}/{check_chunk(cloud, 'cloud')}/sim/control"
