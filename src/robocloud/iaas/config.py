"""The IaaS's settings: one class, read from flags and the environment, built in the CLI.

Nothing here is read when a module is imported: ``Settings.from_env`` is called
by ``robocloud iaas`` and by tests, which may also build ``Settings`` directly.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from robocloud.errors import InvalidInput
from robocloud.federation.security import OverlaySecurity

API_KEYS_ENV = "ROBOCLOUD_API_KEYS"


def parse_api_keys(text: str) -> dict[str, str]:
    """``"wildfire=s3cret,demo=k2"`` -> key -> application.

    Several applications may not share a key: the key is what tells them apart.
    """
    keys: dict[str, str] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        application, sep, key = item.partition("=")
        application, key = application.strip(), key.strip()
        if not sep or not application or not key:
            raise InvalidInput(
                f"{API_KEYS_ENV} must be comma-separated application=key pairs; "
                f"{item!r} is not one.",
                API_KEYS_ENV,
            )
        if key in keys and keys[key] != application:
            raise InvalidInput(
                f"applications {keys[key]!r} and {application!r} share a key.", API_KEYS_ENV
            )
        keys[key] = application
    return keys


@dataclass(frozen=True)
class Settings:
    cloud: str
    host: str = "127.0.0.1"
    port: int = 8101
    zenoh_listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    zenoh_peers: tuple[str, ...] = ()
    store_url: str = ""
    api_keys: Mapping[str, str] = field(default_factory=dict)  # key -> application
    offline_after: float = 5.0  # seconds of silence before a robot is offline
    max_body_bytes: int = 64 * 1024
    optimizer: str = "auto"
    seed: int = 0
    reselect_attempts: int = 8  # selections per request when reservations conflict
    ack_timeout: float = 2.0  # seconds a robot has to acknowledge a command
    # A robot silent this long is forgotten (memory stays bounded whatever
    # ids robots come and go with); at most max_fleet robots are followed.
    forget_after: float = 600.0
    max_fleet: int = 100_000
    # Load shedding (RequestService.busy): new requests are refused (503)
    # while this many wait for their robots, or while 8 or more wait and the
    # oldest has waited busy_after seconds.
    max_waiting: int = 1000
    busy_after: float = 0.5
    cancel_timeout: float = 15.0  # seconds a cancel waits for its state to be stored
    # The watchdog (robocloud.iaas.lifecycle, docs/model.md): a robot may take
    # its expected time plus the larger of overrun_ratio of it and overrun_min
    # wall seconds; stall_after seconds without progress while it
    # travels or works is a stall. A robot that fails so (or gives no ack) twice
    # in a row is set aside for set_aside_for seconds.
    overrun_ratio: float = 0.5
    overrun_min: float = 30.0
    stall_after: float = 30.0
    set_aside_for: float = 300.0
    # Selections run in worker processes (robocloud.iaas.selector); 0: in a
    # thread of the IaaS (for fast tests). The budget is the time a selection
    # may take; its worker is stopped a second after it.
    selection_workers: int = 2
    selection_budget: float = 2.0
    selection_memory_mb: int = 1024
    # Simulated robots may run faster than the wall clock (``robocloud sim
    # --speedup``); the time left for a replacement is counted in robot time.
    time_scale: float = 1.0
    # Federation: the clouds whose commands for this cloud's robots are
    # accepted (empty: every cloud on the overlay), and how long a request
    # waits for the other clouds' idle robots.
    trusted: tuple[str, ...] = ()
    gather_timeout: float = 0.5
    # Loans of this cloud's robots to other clouds (robocloud.federation.home): the
    # longest lease granted until the dispatch, and how long an origin may
    # stay unreachable once its robot is idle or done before losing the loan.
    lease_max: float = 30.0
    origin_deadline: float = 60.0
    lend_share: float = 0.5  # of this cloud's robots one other cloud holds at most
    federation: bool = True
    # An HTTP connection whose request line and headers are not all in this
    # many seconds after it opened (or after the request's first byte) is
    # closed (robocloud.cli.serving): a client cannot hold one for ever.
    header_timeout: float = 10.0
    # TLS, logins and access control on the overlay (docs/security.md); None:
    # plain TCP, for one machine.
    overlay_security: OverlaySecurity | None = None

    def __post_init__(self) -> None:
        if not self.store_url:
            object.__setattr__(self, "store_url", default_store_url(self.cloud))

    @classmethod
    def from_env(
        cls, cloud: str, environ: Mapping[str, str] | None = None, **overrides: object
    ) -> Settings:
        env = os.environ if environ is None else environ
        keys = parse_api_keys(env.get(API_KEYS_ENV, ""))
        given = overrides.pop("api_keys", None)
        if isinstance(given, Mapping):
            keys = {**keys, **given}
        return cls(cloud=cloud, api_keys=keys, **overrides)  # type: ignore[arg-type]


def default_store_url(cloud: str) -> str:
    return f"sqlite:///{Path('var') / f'{cloud}.db'}"
