"""Who may ask what of a cloud's router: Zenoh ``access_control`` from the overlay's keys.

A cloud's router denies by default and allows:

- everyone: every message but queries, both ways; queries going out; queries
  coming in for the questions every cloud answers (``robocloud/*/info`` ...),
  the scatter-gather of the federation;
- each trusted cloud: queries coming in on the command keys that name it as
  the sender, ``robocloud/<this cloud>/from/<trusted cloud>/<command>``, and
  no other command key. So a command's key is proof of its sender, and the
  home takes the origin from it: cloud C cannot send as cloud A, and nobody
  else, a robot's certificate included, sends commands at all;
- this cloud itself (its own certificate or user, e.g. its operators' tools):
  every query.

Allow rules and deny by default, never deny rules: Zenoh applies a rule to a
message whose key the rule's key includes, so a deny rule on one command key
would miss a query on ``robocloud/**``. Nobody else may query this cloud's
robots' command keys: commands reach them through this cloud's IaaS, which
checks who holds the robot.

Peers are known by their certificate's common name with mutual TLS. With
logins only, a router knows the user of the peers that connected to it, not
of those it connected to, so the command keys stay open to every peer let in
(the origin in the key is then as good as the network): docs/security.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from robocloud.errors import InvalidInput
from robocloud.federation import keys
from robocloud.fleet.keys import check_chunk

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


def access_control(
    cloud: str, trusted: Sequence[str] = (), by_certificate: bool = True
) -> dict[str, Any]:
    """Zenoh ``access_control`` for the router of ``cloud`` (see the module's docstring)."""
    trusted = check_trusted(cloud, trusted, by_certificate)
    by = "cert_common_names" if by_certificate else "usernames"
    rules: list[dict[str, Any]] = [
        _rule("messages", ["ingress", "egress"], list(_NOT_QUERIES), ["**"]),
        _rule("ask", ["egress"], ["query"], ["**"]),
        _rule("answer", ["ingress"], ["query"], [keys.question("*", q) for q in QUESTIONS]),
        _rule("everything", ["ingress"], ["query"], ["**"]),
    ]
    subjects: list[dict[str, Any]] = [{"id": "anyone"}, {"id": "itself", by: [cloud]}]
    policies: list[dict[str, Any]] = [
        {"id": "anyone", "subjects": ["anyone"], "rules": ["messages", "ask", "answer"]},
        {"id": "itself", "subjects": ["itself"], "rules": ["everything"]},
    ]
    if by_certificate:
        for name in trusted:
            rules.append(
                _rule(
                    f"commands-from-{name}",
                    ["ingress"],
                    ["query"],
                    [keys.command(cloud, name, c) for c in COMMANDS],
                )
            )
            subjects.append({"id": f"cloud-{name}", by: [name]})
            policies.append(
                {
                    "id": f"trusted-{name}",
                    "subjects": [f"cloud-{name}"],
                    "rules": [f"commands-from-{name}"],
                }
            )
    else:
        rules.append(
            _rule(
                "commands", ["ingress"], ["query"], [keys.command(cloud, "*", c) for c in COMMANDS]
            )
        )
        policies[0]["rules"].append("commands")
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
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
