"""The gateway's Prometheus metrics (``robocloud vda5050 --metrics HOST:PORT``).

Read from the gateway at each scrape. The names (docs/metrics.md):

- ``robocloud_vda5050_agvs{status}``: the AGVs by the status their robot shows now
- ``robocloud_vda5050_stale_states_total``: states ignored as older than, or the
  same as, one already taken (``headerId``, ``timestamp``)
- ``robocloud_vda5050_orders_not_accepted_total``: orders whose ``orderId`` and
  ``orderUpdateId`` the AGV's state did not show in time (the task failed, the
  order was cancelled)
- ``robocloud_vda5050_reconcile_cancels_total``: ``cancelOrder`` sent by the
  gateway on its own, for an order robocloud no longer gives that AGV (an order
  found after a restart, a task that failed or went silent)
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

from prometheus_client import CollectorRegistry, start_http_server
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector

if TYPE_CHECKING:
    from prometheus_client.metrics_core import Metric

    from robocloud.gateways.vda5050.gateway import Vda5050Gateway

STATUSES = ("idle", "reserved", "busy", "charging", "offline")


class GatewayCollector(Collector):
    def __init__(self, gateway: Vda5050Gateway) -> None:
        self.gateway = gateway

    def collect(self) -> Iterator[Metric]:
        numbers = self.gateway.numbers()
        agvs = GaugeMetricFamily(
            "robocloud_vda5050_agvs", "The gateway's AGVs by robot status now.", labels=["status"]
        )
        counts = numbers.statuses
        for status in sorted(set(STATUSES) | set(counts)):
            agvs.add_metric([status], counts.get(status, 0))
        yield agvs
        for name, text, value in (
            ("stale_states", "AGV states ignored: not newer than one taken.", numbers.stale),
            (
                "orders_not_accepted",
                "Orders the AGV's state did not show in time (task failed, order cancelled).",
                numbers.not_accepted,
            ),
            (
                "reconcile_cancels",
                "cancelOrder sent by the gateway for an order robocloud no longer gives the AGV.",
                numbers.reconcile_cancels,
            ),
        ):
            family = CounterMetricFamily(f"robocloud_vda5050_{name}", text)
            family.add_metric([], value)
            yield family


def serve_metrics(gateway: Vda5050Gateway, host: str, port: int) -> None:
    """Serve ``/metrics`` of ``gateway`` on ``host:port`` from a daemon thread."""
    registry = CollectorRegistry(auto_describe=False)
    registry.register(GatewayCollector(gateway))
    start_http_server(port, addr=host, registry=registry)
