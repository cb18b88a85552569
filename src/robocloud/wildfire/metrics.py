"""The wildfire server's metrics (``GET /metrics``, the Prometheus text format); docs/metrics.md.

A registry per app, like the IaaS's (``robocloud.iaas.metrics``). Counters
move in the routes; what the feed and the IaaS clients already count (open
pages, bytes sent, failed calls) is read at scrape.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

from prometheus_client import CollectorRegistry, Counter, disable_created_metrics
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.exposition import choose_encoder

if TYPE_CHECKING:
    from robocloud.wildfire.feed import LiveFeed
    from robocloud.wildfire.iaas_pool import IaasPool

disable_created_metrics()  # type: ignore[no-untyped-call]  # as robocloud.iaas.metrics

SEND_OUTCOMES = ("accepted", "refused", "failed", "unknown")


class WildfireMetrics:
    def __init__(self) -> None:
        self.registry = CollectorRegistry(auto_describe=True)
        r = self.registry
        self.page_loads = Counter(
            "wildfire_page_loads", "Times the page (GET /) was served.", registry=r
        )
        self.live_connections = Counter(
            "wildfire_live_connections",
            "Live streams (GET /api/live) opened by pages.",
            registry=r,
        )
        self.sends = Counter(
            "wildfire_sends",
            "Requests sent by the page (POST /api/requests), by outcome: accepted by an "
            "IaaS, refused (4xx), failed (an IaaS's 5xx), unknown (no answer: maybe delivered).",
            ["outcome"],
            registry=r,
        )
        self.mission_sends = Counter(
            "wildfire_mission_sends",
            "Missions sent by the page (POST /api/missions), by outcome, as for requests.",
            ["outcome"],
            registry=r,
        )
        for outcome in SEND_OUTCOMES:
            self.sends.labels(outcome)
            self.mission_sends.labels(outcome)
        self._reads = _Reads()
        r.register(self._reads)

    def watch(self, feed: LiveFeed, pool: IaasPool) -> None:
        """What the gauges read at scrape: the feed's pages and the pool's IaaS clients."""
        self._reads.feed, self._reads.pool = feed, pool

    def exposition(self, accept: str | None) -> tuple[bytes, str]:
        encode, content_type = choose_encoder(accept or "")
        return encode(self.registry), content_type


class _Reads:
    def __init__(self) -> None:
        self.feed: LiveFeed | None = None
        self.pool: IaasPool | None = None

    def describe(self) -> list[Metric]:
        return []

    def collect(self) -> Iterator[Metric]:
        pages = GaugeMetricFamily("wildfire_live_pages", "Pages following the live stream now.")
        pages.add_metric([], len(self.feed.subscribers) if self.feed else 0)
        yield pages
        sent = CounterMetricFamily(
            "wildfire_live_sent_bytes", "Bytes of the live stream sent to the pages (compressed)."
        )
        sent.add_metric([], self.feed.sent_bytes if self.feed else 0)
        yield sent
        errors = CounterMetricFamily(
            "wildfire_upstream_errors",
            "Calls to an IaaS that got no usable answer or a 5xx, by the IaaS's URL.",
            labels=["iaas"],
        )
        for endpoint in self.pool.endpoints if self.pool else ():
            errors.add_metric([endpoint.url], endpoint.client.failures)
        yield errors
