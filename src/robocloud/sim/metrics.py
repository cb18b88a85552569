"""The fleet simulator's Prometheus metrics (``robocloud sim --metrics HOST:PORT``).

Read from the simulator at each scrape, so the simulation loop pays nothing
for them but a few counters. The names (docs/metrics.md):

- ``robocloud_sim_robots{status}``: the simulated robots by status now
- ``robocloud_sim_states_published_total``: states sent (a batch counts its states)
- ``robocloud_sim_commands_total{command,outcome}``: commands answered
  (``assign`` or ``cancel``; ``accepted`` or ``refused``)
- ``robocloud_sim_ticks_total`` and ``robocloud_sim_late_ticks_total``: steps of
  the simulation, and those that started late (the machine could not keep up)
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator, Mapping
from typing import TYPE_CHECKING, Protocol

from prometheus_client import CollectorRegistry, start_http_server
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector

if TYPE_CHECKING:
    from prometheus_client.metrics_core import Metric

STATUSES = ("idle", "reserved", "busy", "charging", "offline")


class Counted(Protocol):
    """What a scrape reads of the simulator (``robocloud.sim.fleet.FleetSimulator``)."""

    @property
    def states_published(self) -> int: ...
    @property
    def commands_answered(self) -> Mapping[tuple[str, str], int]: ...
    @property
    def ticks(self) -> int: ...
    @property
    def late_ticks(self) -> int: ...

    def status_counts(self) -> Mapping[str, int]: ...


class SimulatorCollector(Collector):
    def __init__(self, simulator: Counted) -> None:
        self.simulator = simulator

    def collect(self) -> Iterator[Metric]:
        sim = self.simulator
        robots = GaugeMetricFamily(
            "robocloud_sim_robots", "Simulated robots by status now.", labels=["status"]
        )
        counts = sim.status_counts()
        for status in sorted(set(STATUSES) | set(counts)):
            robots.add_metric([status], counts.get(status, 0))
        yield robots
        published = CounterMetricFamily(
            "robocloud_sim_states_published", "States the simulator sent."
        )
        published.add_metric([], sim.states_published)
        yield published
        commands = CounterMetricFamily(
            "robocloud_sim_commands",
            "Commands the simulated robots answered.",
            labels=["command", "outcome"],
        )
        for (command, outcome), n in sorted(sim.commands_answered.items()):
            commands.add_metric([command, outcome], n)
        yield commands
        ticks = CounterMetricFamily("robocloud_sim_ticks", "Steps of the simulation.")
        ticks.add_metric([], sim.ticks)
        yield ticks
        late = CounterMetricFamily(
            "robocloud_sim_late_ticks", "Steps that started late: the machine fell behind."
        )
        late.add_metric([], sim.late_ticks)
        yield late


def metrics_address(text: str) -> tuple[str, int]:
    """``127.0.0.1:9101`` or ``9101`` (on 127.0.0.1) -> (host, port); argparse's type."""
    host, _, port = text.rpartition(":")
    if not port.isdigit() or not 0 < int(port) < 65536:
        raise argparse.ArgumentTypeError(f"{text!r} is not HOST:PORT or PORT")
    return host.strip("[]") or "127.0.0.1", int(port)


def serve_metrics(simulator: Counted, host: str, port: int) -> None:
    """Serve ``/metrics`` of ``simulator`` on ``host:port`` from a daemon thread."""
    registry = CollectorRegistry(auto_describe=False)
    registry.register(SimulatorCollector(simulator))
    start_http_server(port, addr=host, registry=registry)
