"""Who speaks for each cloud on the overlay: the session that declared its presence.

Every IaaS declares a liveliness token that names its cloud and its own
Zenoh session id (``robocloud/federation/clouds/<cloud>/<zid>``,
``robocloud.federation.keys``). A reply counts only when Zenoh says it comes
from that session (``reply.replier_id``): a queryable someone else declared
on ``robocloud/<cloud>/...`` (a robot's certificate, another member cloud)
answers into the void, and the asker logs and counts it. What the asker
trusts is Zenoh's own account of who replied, never the payload.

A cloud is usable only when this cloud trusts it (``trusts``; the home's
``--trust``: borrow only from the clouds one lends to) and exactly one
session claims it. Two sessions claiming one cloud (a forger beside the real
IaaS, where the router's access control is off) make it unusable until one
goes: guessing which is real is what the forger wants.

Pure bookkeeping, no Zenoh: ``ZenohOverlay`` feeds it tokens and replies.
"""

from __future__ import annotations

import logging
import threading
from collections import Counter
from collections.abc import Callable

log = logging.getLogger(__name__)


class Presence:
    """The clouds present on the overlay, the session of each, and the replies refused."""

    def __init__(self, cloud: str, zid: str, trusts: Callable[[str], bool]) -> None:
        self.cloud = cloud
        self.zid = zid
        self._trusts = trusts
        self._lock = threading.Lock()
        self._claims: dict[str, set[str]] = {cloud: {zid}}
        self._usable: list[str] = [cloud]  # sorted, this one included; replaced whole
        # (what was asked, why the reply was refused) -> how many: the metric.
        self.refused: Counter[tuple[str, str]] = Counter()

    # -- tokens ------------------------------------------------------------------

    def came(self, cloud: str, zid: str) -> None:
        """A session declared the presence of ``cloud``."""
        with self._lock:
            claims = self._claims.setdefault(cloud, set())
            if zid in claims:
                return
            claims.add(zid)
            self._refresh()
            many = len(claims) > 1
        if cloud == self.cloud and zid != self.zid:
            log.warning(
                "session %s declares the presence of %s, which is this IaaS (session %s): ignored",
                zid,
                cloud,
                self.zid,
            )
        elif many:
            log.warning(
                "%d sessions declare the presence of %s (%s): it is left out until one goes",
                len(claims),
                cloud,
                ", ".join(sorted(claims)),
            )
        elif not self._trusts(cloud):
            log.warning(
                "%s is present (session %s) but %s does not trust it: it is neither asked "
                "nor answered",
                cloud,
                zid,
                self.cloud,
            )
        else:
            log.info("%s is present (session %s)", cloud, zid)

    def went(self, cloud: str, zid: str) -> None:
        """The session ``zid`` withdrew its presence of ``cloud`` (or went away)."""
        if cloud == self.cloud and zid == self.zid:
            return
        with self._lock:
            claims = self._claims.get(cloud)
            if claims is None or zid not in claims:
                return
            claims.discard(zid)
            if not claims:
                del self._claims[cloud]
            self._refresh()

    def _refresh(self) -> None:
        """The usable clouds again (the caller holds the lock)."""
        self._usable = sorted(
            cloud
            for cloud, claims in self._claims.items()
            if cloud == self.cloud or (len(claims) == 1 and self._trusts(cloud))
        )

    def clouds(self) -> list[str]:
        """The usable clouds (trusted, one session each), this one included, sorted."""
        return list(self._usable)

    def owner(self, cloud: str) -> str | None:
        """The session that speaks for ``cloud``; None when it is not usable."""
        if cloud == self.cloud:
            return self.zid
        with self._lock:
            claims = self._claims.get(cloud)
            if not claims or len(claims) != 1 or not self._trusts(cloud):
                return None
            return next(iter(claims))

    # -- replies ------------------------------------------------------------------

    def speaks_for(self, cloud: str, replier: str | None, what: str) -> bool:
        """Whether a reply about ``cloud`` to the question ``what`` comes from its session.

        A reply that does not is logged and counted (``refused``).
        """
        owner = self.owner(cloud)
        if replier is not None and replier == owner:
            return True
        why = "untrusted" if owner is None else "forged"
        with self._lock:
            self.refused[(what, why)] += 1
            count = self.refused[(what, why)]
        # An attacker may send many: the first of each kind, then every hundredth.
        if count != 1 and count % 100 != 0:
            return False
        if owner is None:
            log.warning(
                "dropped a reply to the %s from session %s for %s, which is not a "
                "cloud %s asks (%d such replies so far)",
                what,
                replier,
                cloud,
                self.cloud,
                count,
            )
            return False
        log.warning(
            "dropped a forged reply to the %s: it claims to be %s's but comes from session "
            "%s, not %s's session %s (%d forged %s replies so far)",
            what,
            cloud,
            replier,
            cloud,
            owner,
            count,
            what,
        )
        return False

    def refusals(self) -> dict[tuple[str, str], int]:
        """A copy of ``refused``: (question or command, forged or untrusted) -> count."""
        with self._lock:
            return dict(self.refused)
