"""Security between clouds on the Zenoh overlay, with Zenoh's own mechanisms (docs/security.md).

::

    configuration   OverlaySecurity: TLS files, logins, whom a router trusts; the CLI flags
    policy          the router's access control: questions for all, commands by sender key
    certificates    make-certs: a CA and a certificate per cloud (the cryptography package)

``python -m robocloud.federation.security make-certs ...`` makes certificates.
The certificate names are imported when first used, so the command-line
parser, which reads the flags from here, stays quick to import.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from robocloud.federation.security.configuration import (
    OverlaySecurity,
    add_arguments,
    from_arguments,
    read_credentials,
)

if TYPE_CHECKING:
    from robocloud.federation.security.certificates import (
        DEFAULT_HOSTS,
        Issued,
        main,
        make_certs,
    )
    from robocloud.federation.security.policy import COMMANDS, QUESTIONS, access_control

_LAZY = {
    "DEFAULT_HOSTS": "certificates",
    "Issued": "certificates",
    "main": "certificates",
    "make_certs": "certificates",
    "COMMANDS": "policy",
    "QUESTIONS": "policy",
    "access_control": "policy",
}

__all__ = [
    "COMMANDS",
    "DEFAULT_HOSTS",
    "QUESTIONS",
    "Issued",
    "OverlaySecurity",
    "access_control",
    "add_arguments",
    "from_arguments",
    "main",
    "make_certs",
    "read_credentials",
]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(f"{__name__}.{module}"), name)
