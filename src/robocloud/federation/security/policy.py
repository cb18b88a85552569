"""Who may say what on a cloud's router: Zenoh ``access_control`` by certificate name.

Each session's certificate says what it is (its common name, made by
``make-certs``): a cloud (its name), the fleet of a cloud (``<cloud>-robots``:
its robots, simulators and gateways), one robot of a cloud
(``<cloud>-robot-<id>``, for the ids the router is given), or anything else
the federation's CA signed. The router of cloud X denies by default; what comes in (ingress) is
allowed by list:

- **X itself** (its own certificate: its IaaS's tools): everything;
- **X's fleet** (``X-robots``): states and batches on X's robot and fleet
  keys (``robocloud/X/robots/*/state``, ``robocloud/X/fleets/*/states``); a
  queryable and its replies on X's robots' command keys and the simulator's
  control key; the simulator's liveliness token. Not another cloud's keys,
  not a presence token, not a reply to a cloud's question: a robot's
  certificate cannot fabricate a cloud or answer for one;
- **one gateway G of X** (``X-gateway-G``, when G is among the router's
  gateways, with the robots it fronts): states on its own batch key
  (``robocloud/X/fleets/G/states``) and on its robots' state keys; a
  queryable and its replies on its robots' command keys, one by one (not the
  wildcard ``robots/*/cmd``). That a batch holds only its robots' states is
  the IaaS's check (``fleet/link.py``): the router does not read payloads;
- **one robot R of X** (``X-robot-R``, when R is among the router's robot
  ids): its own state (``robocloud/X/robots/R/state``), a queryable and its
  replies on its own command key (``robocloud/X/robots/R/cmd``); nothing of
  another robot, no batch, no token. It subscribes to its error key as
  everyone may subscribe;
- **each trusted cloud T**: queries on the command keys that name it as the
  sender, ``robocloud/X/from/T/<command>``; and as a cloud: its presence
  token (``robocloud/federation/clouds/T/*``), queryables and replies on its
  own keys (``robocloud/T/**``), its robots' states on its own keys;
- **everyone**: subscriptions, liveliness subscriptions and queries, and
  queries for the questions every cloud answers (``robocloud/*/info`` ...).

What goes out (egress) is not restricted: it is what X's own router sends.
So cloud C cannot send as cloud A, answer for A, or declare A's presence;
nobody queries X's robots directly; an untrusted member's presence and
replies never reach X's IaaS. Allow rules and deny by default, never deny
rules: Zenoh applies a rule to a message whose key the rule's key includes,
so a deny rule on one command key would miss a query on ``robocloud/**``.

Peers are known by their certificate's common name with mutual TLS. With
logins only, a router knows the user of the peers that connected to it, not
of those it connected to, so everything but queries stays open to every peer
let in, and the command keys to every login (docs/security.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from robocloud.errors import InvalidInput
from robocloud.federation import keys
from robocloud.federation.keys import CLOUDS_TOKEN
from robocloud.fleet import keys as robot_keys
from robocloud.fleet.keys import ROOT, check_chunk

QUESTIONS = keys.QUESTIONS
COMMANDS = keys.COMMANDS

# Every message kind of Zenoh's access control except ``query``.
_NOT_QUERIES = (
    "put",
    "delete",
    "declare_subscriber",
    "declare_queryable",
    "reply",
    "liveliness_token",
    "liveliness_query",
    "declare_liveliness_subscriber",
)

NO_TRUST = (
    "with mutual TLS the router gives the command keys for {cloud}'s robots only to the "
    "clouds it trusts, and it trusts none: name them with --trust CLOUD (repeatable)."
)


def check_trusted(cloud: str, trusted: Sequence[str], by_certificate: bool) -> tuple[str, ...]:
    """The trusted clouds, checked: key chunks, and at least one when peers show certificates.

    An empty list used to mean "every member", which with certificates would
    include the robots' own; a member list is what the router enforces.
    """
    names = tuple(sorted({check_chunk(name, "trusted cloud") for name in trusted}))
    if by_certificate and not names:
        raise InvalidInput(NO_TRUST.format(cloud=cloud), field="trust")
    return names


def fleet_name(cloud: str) -> str:
    """The common name of a cloud's fleet certificate (its robots, simulators, gateways)."""
    return f"{cloud}-robots"


def robot_name(cloud: str, robot_id: str) -> str:
    """The common name of one robot's own certificate: it speaks for that robot only."""
    return f"{cloud}-robot-{robot_id}"


def gateway_name(cloud: str, gateway: str) -> str:
    """The common name of a gateway's own certificate: it speaks for its robots only."""
    return f"{cloud}-gateway-{gateway}"


def check_gateways(
    gateways: Sequence[tuple[str, Sequence[str]]],
) -> tuple[tuple[str, tuple[str, ...]], ...]:
    """Gateways with their robots, checked: key chunks, each gateway once, each robot in one."""
    checked: dict[str, tuple[str, ...]] = {}  # gateway -> its robots, in the given order
    owner: dict[str, str] = {}
    for name, ids in gateways:
        gateway = check_chunk(name, "gateway name")
        if gateway in checked:
            raise InvalidInput(f"the gateway {gateway!r} is listed twice.", field="gateways")
        robots = check_robot_ids(ids)
        for rid in robots:
            if rid in owner:
                raise InvalidInput(
                    f"robot {rid!r} is listed for gateways {owner[rid]!r} and {gateway!r}: "
                    "a robot is fronted by one gateway.",
                    field="gateways",
                )
            owner[rid] = gateway
        checked[gateway] = robots
    return tuple(checked.items())


def check_robot_ids(robot_ids: Sequence[str]) -> tuple[str, ...]:
    """The robot ids that have their own certificate, checked: key chunks, each once."""
    names = tuple(check_chunk(rid, "robot id") for rid in robot_ids)
    seen: set[str] = set()
    for rid in names:
        if rid in seen:
            raise InvalidInput(f"the robot id {rid!r} is listed twice.", field="robot_ids")
        seen.add(rid)
    return names


def access_control(
    cloud: str,
    trusted: Sequence[str] = (),
    by_certificate: bool = True,
    robot_ids: Sequence[str] = (),
    gateways: Sequence[tuple[str, Sequence[str]]] = (),
) -> dict[str, Any]:
    """Zenoh ``access_control`` for the router of ``cloud`` (see the module's docstring).

    ``robot_ids``: the robots of ``cloud`` with a certificate of their own
    (``robot_name``); each gets one subject and its own keys only.
    ``gateways``: the gateways of ``cloud`` with a certificate of their own
    (``gateway_name``) and the robots each fronts; each gets one subject and
    the keys of its robots only.
    """
    trusted = check_trusted(cloud, trusted, by_certificate)
    if not by_certificate:
        return _by_login(cloud)
    by = "cert_common_names"
    everything = [*_NOT_QUERIES, "query"]
    own = f"{ROOT}/{cloud}"
    rules: list[dict[str, Any]] = [
        _rule("out", ["egress"], everything, ["**"]),
        _rule(
            "listen",
            ["ingress"],
            ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"],
            ["**"],
        ),
        _rule("answer", ["ingress"], ["query"], [keys.question("*", q) for q in QUESTIONS]),
        _rule("everything", ["ingress"], everything, ["**"]),
        _rule(
            "fleet-states",
            ["ingress"],
            ["put"],
            [robot_keys.all_states(cloud), robot_keys.all_batches(cloud)],
        ),
        _rule(
            "fleet-commands",
            ["ingress"],
            ["declare_queryable", "reply"],
            [robot_keys.all_cmds(cloud), robot_keys.sim_control(cloud)],
        ),
        _rule("fleet-presence", ["ingress"], ["liveliness_token"], [f"{own}/sim/*"]),
    ]
    subjects: list[dict[str, Any]] = [
        {"id": "anyone"},
        {"id": "itself", by: [cloud]},
        {"id": "fleet", by: [fleet_name(cloud)]},
    ]
    policies: list[dict[str, Any]] = [
        {"id": "anyone", "subjects": ["anyone"], "rules": ["out", "listen", "answer"]},
        {"id": "itself", "subjects": ["itself"], "rules": ["everything"]},
        {
            "id": "fleet",
            "subjects": ["fleet"],
            "rules": ["fleet-states", "fleet-commands", "fleet-presence"],
        },
    ]
    for rid in check_robot_ids(robot_ids):
        rules += [
            _rule(f"state-of-{rid}", ["ingress"], ["put"], [robot_keys.state_key(cloud, rid)]),
            _rule(
                f"commands-of-{rid}",
                ["ingress"],
                ["declare_queryable", "reply"],
                [robot_keys.cmd_key(cloud, rid)],
            ),
        ]
        subjects.append({"id": f"robot-{rid}", by: [robot_name(cloud, rid)]})
        policies.append(
            {
                "id": f"robot-{rid}",
                "subjects": [f"robot-{rid}"],
                "rules": [f"state-of-{rid}", f"commands-of-{rid}"],
            }
        )
    for gateway, ids in check_gateways(gateways):
        rules += [
            _rule(
                f"gateway-{gateway}-states",
                ["ingress"],
                ["put"],
                [robot_keys.batch_key(cloud, gateway)]
                + [robot_keys.state_key(cloud, rid) for rid in ids],
            ),
            _rule(
                f"gateway-{gateway}-commands",
                ["ingress"],
                ["declare_queryable", "reply"],
                [robot_keys.cmd_key(cloud, rid) for rid in ids],
            ),
        ]
        subjects.append({"id": f"gateway-{gateway}", by: [gateway_name(cloud, gateway)]})
        policies.append(
            {
                "id": f"gateway-{gateway}",
                "subjects": [f"gateway-{gateway}"],
                "rules": [f"gateway-{gateway}-states", f"gateway-{gateway}-commands"],
            }
        )
    for name in trusted:
        if name == cloud:
            continue  # itself: everything already
        rules += [
            _rule(
                f"commands-from-{name}",
                ["ingress"],
                ["query"],
                [keys.command(cloud, name, c) for c in COMMANDS],
            ),
            _rule(
                f"presence-of-{name}",
                ["ingress"],
                ["liveliness_token"],
                [f"{CLOUDS_TOKEN}/{name}/*"],
            ),
            _rule(
                f"answers-of-{name}",
                ["ingress"],
                ["declare_queryable", "reply"],
                [f"{ROOT}/{name}/**"],
            ),
            _rule(
                f"states-of-{name}",
                ["ingress"],
                ["put"],
                [robot_keys.all_states(name), robot_keys.all_batches(name)],
            ),
        ]
        subjects.append({"id": f"cloud-{name}", by: [name]})
        policies.append(
            {
                "id": f"trusted-{name}",
                "subjects": [f"cloud-{name}"],
                "rules": [
                    f"commands-from-{name}",
                    f"presence-of-{name}",
                    f"answers-of-{name}",
                    f"states-of-{name}",
                ],
            }
        )
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def _by_login(cloud: str) -> dict[str, Any]:
    """With logins only: every message but queries open; commands to every login."""
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": [
            _rule("messages", ["ingress", "egress"], list(_NOT_QUERIES), ["**"]),
            _rule("ask", ["egress"], ["query"], ["**"]),
            _rule("answer", ["ingress"], ["query"], [keys.question("*", q) for q in QUESTIONS]),
            _rule("everything", ["ingress"], ["query"], ["**"]),
            _rule(
                "commands",
                ["ingress"],
                ["query"],
                [keys.command(cloud, "*", c) for c in COMMANDS],
            ),
        ],
        "subjects": [{"id": "anyone"}, {"id": "itself", "usernames": [cloud]}],
        "policies": [
            {
                "id": "anyone",
                "subjects": ["anyone"],
                "rules": ["messages", "ask", "answer", "commands"],
            },
            {"id": "itself", "subjects": ["itself"], "rules": ["everything"]},
        ],
    }


def _rule(
    rule_id: str, flows: list[str], messages: list[str], key_exprs: list[str]
) -> dict[str, Any]:
    return {
        "id": rule_id,
        "permission": "allow",
        "flows": flows,
        "messages": messages,
        "key_exprs": key_exprs,
    }
