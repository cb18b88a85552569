"""The IaaS's metrics, in the Prometheus text format (``GET /metrics``): every name in one place.

Each app has a registry of its own (tests run several IaaSs in one process),
so nothing here is global. The names, their labels and what moves them are
listed in docs/metrics.md; keep the two together.

Counters and histograms are moved where things happen (the request actors,
the service's store calls); the gauges are computed when Prometheus scrapes,
from the robot link, the store's reservations and the service's actors (no
network: each IaaS exports its own cloud, Prometheus adds the federation up).
"""

from __future__ import annotations

from collections import Counter as Tally
from collections.abc import Callable, Iterable, Iterator, Mapping

from prometheus_client import CollectorRegistry, Counter, Histogram, disable_created_metrics
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.exposition import choose_encoder

from robocloud.domain.request import ACTIVE_STATES, FINAL_STATES, REQUEST_STATES
from robocloud.domain.robot import ROBOT_STATUSES

# No ``*_created`` series beside each counter and histogram: noise for a
# dashboard (a switch of the whole process, the same for every IaaS in it).
disable_created_metrics()  # type: ignore[no-untyped-call]

# Seconds. Selections take milliseconds to their budget (seconds); a dispatch
# waits for a selection and the robots' acks (up to the ack timeout).
FAST_BUCKETS = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0)
SLOW_BUCKETS = (0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0)
COMMANDS = ("assign", "stop")
OVERLAY_OPERATIONS = ("gather", "dispatch", "cancel")

RobotCounts = Callable[[], Iterable[tuple[str, str]]]  # (cloud, status) of each robot
ActiveStates = Callable[[], Iterable[str]]  # the state of each active request
# (what was asked, forged or untrusted) -> replies dropped (robocloud.federation.presence)
DroppedReplies = Callable[[], Mapping[tuple[str, str], int]]
RefusedReserves = Callable[[], Mapping[str, int]]  # origin -> reservations refused by a bound
# (party, message) -> messages the router's access control refused
# (robocloud.federation.security.router_refusals)
RouterRefusals = Callable[[], Mapping[tuple[str, str], int]]
# field -> robot states refused for it, and "overtaken" (robocloud.fleet.link)
StateRefusals = Callable[[], Mapping[str, int]]


class IaasMetrics:
    """The metrics of one IaaS; ``exposition`` is what ``GET /metrics`` answers."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry(auto_describe=True)
        r = self.registry
        self.transitions = Counter(
            "robocloud_request_transitions",
            "Times a request entered a state (received: accepted by POST /v1/requests, "
            "an idempotent retry not counted).",
            ["state"],
            registry=r,
        )
        self.finished = Counter(
            "robocloud_requests_finished",
            "Requests that reached a final state, by that state.",
            ["outcome"],
            registry=r,
        )
        self.selection_seconds = Histogram(
            "robocloud_selection_seconds",
            "Wall time of one selection (the pipeline, in a worker process or a thread).",
            buckets=FAST_BUCKETS,
            registry=r,
        )
        self.dispatch_seconds = Histogram(
            "robocloud_post_to_dispatched_seconds",
            "From the POST of a request to its dispatched state (selected, reserved, acked).",
            buckets=SLOW_BUCKETS,
            registry=r,
        )
        self.ack_seconds = Histogram(
            "robocloud_command_ack_seconds",
            "From sending a command to a robot of this cloud to its acknowledgement "
            "(or the ack timeout).",
            ["command"],
            buckets=FAST_BUCKETS,
            registry=r,
        )
        self.overlay_seconds = Histogram(
            "robocloud_overlay_seconds",
            "Calls to other clouds over the federation overlay: gathering idle robots, "
            "and commands to borrowed robots.",
            ["operation"],
            buckets=FAST_BUCKETS,
            registry=r,
        )
        self.refused = Counter(
            "robocloud_requests_refused_busy",
            "New requests refused with 503 because the cloud was busy (load shedding: "
            "too many requests waiting for their robots, or waiting too long).",
            registry=r,
        )
        self.store_errors = Counter(
            "robocloud_store_errors",
            "Store calls that found the store unavailable, by the store's method.",
            ["operation"],
            registry=r,
        )
        self.robot_failures = Counter(
            "robocloud_robot_failures",
            "Robots that failed their part of a request, by cause: no_ack (no answer to the "
            "assign within the ack deadline), overrun (past its expected finish plus the "
            "tolerance: the watchdog), stalled (no progress reported), offline, silent, "
            "reported (the robot said it cannot finish), dropped (it stopped reporting the "
            "request), loan_ended.",
            ["cause"],
            registry=r,
        )
        self.stops = Counter(
            "robocloud_stops",
            "Stop commands sent to robots: request (a request's own stop: a robot failed, "
            "refused, or its request ended) and stray (a robot still working for a request "
            "that does not need it, told again at most once a second).",
            ["kind"],
            registry=r,
        )
        self.set_aside = Counter(
            "robocloud_robots_set_aside",
            "Robots set aside for a cool-down (--set-aside-for) after failing requests in a "
            "row (no ack, stalled, overrun).",
            registry=r,
        )
        # Every label value known in advance shows at 0 from the first scrape.
        for cause in FAILURE_CAUSES:
            self.robot_failures.labels(cause)
        for kind in ("request", "stray"):
            self.stops.labels(kind)
        for state in REQUEST_STATES:
            self.transitions.labels(state)
        for outcome in sorted(FINAL_STATES):
            self.finished.labels(outcome)
        for command in COMMANDS:
            self.ack_seconds.labels(command)

        self._gauges = _Gauges("", lambda: (), lambda: ())
        self.registry.register(self._gauges)
        self._refusals = _Refusals(dict, dict, dict, dict)
        self.registry.register(self._refusals)

    def observe_refusals(self, replies: DroppedReplies, reserves: RefusedReserves) -> None:
        """Where the security counters read at each scrape: the overlay's, the home's."""
        self._refusals.replies, self._refusals.reserves = replies, reserves

    def observe_states_refused(self, refused: StateRefusals) -> None:
        """Where the robot states refused are read at each scrape (the robot link's)."""
        self._refusals.states = refused

    def observe_router(self, refused: RouterRefusals) -> None:
        """Where the router's refusals are read at each scrape (with access control only)."""
        self._refusals.router = refused

    def observe_states(self, cloud: str, robots: RobotCounts, active: ActiveStates) -> None:
        """Where the gauges read at each scrape: the robots (cloud, status), the active requests."""
        self._gauges.cloud, self._gauges.robots, self._gauges.active = cloud, robots, active

    def observe_streams(self, open_streams: Callable[[], int]) -> None:
        """Where the gauge of open event streams reads at each scrape (the request feed)."""
        self._gauges.streams = open_streams

    def entered(self, state: str) -> None:
        self.transitions.labels(state).inc()
        if state in FINAL_STATES:
            self.finished.labels(state).inc()

    def exposition(self, accept: str | None) -> tuple[bytes, str]:
        """The scrape's body and content type (OpenMetrics if the scraper asks for it)."""
        encode, content_type = choose_encoder(accept or "")
        return encode(self.registry), content_type


# Why a robot failed its part of a request (``robocloud.iaas.lifecycle.Failure``).
FAILURE_CAUSES = (
    "no_ack", "overrun", "stalled", "offline", "silent", "reported", "dropped", "loan_ended",
)


class _Gauges:
    """A collector computing its values at scrape time."""

    def __init__(self, cloud: str, robots: RobotCounts, active: ActiveStates) -> None:
        self.cloud = cloud
        self.robots = robots
        self.active = active
        self.streams: Callable[[], int] = lambda: 0

    def describe(self) -> list[Metric]:
        return []  # computed at scrape: nothing to check in advance

    def collect(self) -> Iterator[Metric]:
        robots = GaugeMetricFamily(
            "robocloud_robots",
            "Robots of this cloud the IaaS hears from, by cloud and status "
            "(reserved: idle and held by a request or a loan).",
            labels=["cloud", "status"],
        )
        counts = Tally(self.robots())
        if self.cloud:
            for status in ROBOT_STATUSES:
                counts.setdefault((self.cloud, status), 0)
        for (cloud, status), n in sorted(counts.items()):
            robots.add_metric([cloud, status], n)
        yield robots
        requests = GaugeMetricFamily(
            "robocloud_requests_active",
            "Requests this IaaS is carrying out now, by state.",
            labels=["state"],
        )
        states = Tally(self.active())
        for state in REQUEST_STATES:
            if state in ACTIVE_STATES:
                requests.add_metric([state], states.get(state, 0))
        yield requests
        yield GaugeMetricFamily(
            "robocloud_event_streams",
            "Event streams of requests (GET /v1/requests/{id}/events) open now; a client that "
            "goes away takes its stream with it.",
            value=self.streams(),
        )


class _Refusals:
    """Counters kept by the overlay and the home, read at scrape time."""

    def __init__(
        self,
        replies: DroppedReplies,
        reserves: RefusedReserves,
        router: RouterRefusals,
        states: StateRefusals,
    ) -> None:
        self.replies = replies
        self.reserves = reserves
        self.router = router
        self.states = states

    def describe(self) -> list[Metric]:
        return []

    def collect(self) -> Iterator[Metric]:
        dropped = CounterMetricFamily(
            "robocloud_overlay_replies_dropped",
            "Replies from other clouds dropped because they did not come from the Zenoh "
            "session that declared the cloud's presence (forged), or named a cloud this one "
            "does not trust or that two sessions claim (untrusted); by what was asked.",
            labels=["asked", "why"],
        )
        for (asked, why), n in sorted(self.replies().items()):
            dropped.add_metric([asked, why], n)
        yield dropped
        refused = CounterMetricFamily(
            "robocloud_reservations_refused",
            "Reservations of this cloud's robots refused by a lending bound (lease-max from "
            "the first reservation, idle robots with battery only, the origin's share, the "
            "rate), by the origin cloud.",
            labels=["origin"],
        )
        for origin, n in sorted(self.reserves().items()):
            refused.add_metric([origin], n)
        yield refused
        router = CounterMetricFamily(
            "robocloud_router_refusals",
            "Messages this cloud's Zenoh router dropped because its access control does not "
            "allow them (a robot's certificate declaring a cloud, answering for one, putting "
            "another robot's state...), by the sender's certificate name (or login) and the "
            "kind of message. Counted with access control only (mutual TLS or logins).",
            labels=["party", "message"],
        )
        for (party, message), n in sorted(self.router().items()):
            router.add_metric([party, message], n)
        yield router
        states = CounterMetricFamily(
            "robocloud_states_refused",
            "Robot states this IaaS refused (answered with a StateError), by the field that was "
            "wrong (sent_at: outside the clock bound; id: another robot's key or gateway...), "
            "and 'overtaken': held states that had claimed a sent_at ahead of their arrival and "
            "a greater seq, overtaken by the robot's own (forged, or a restart with the clock "
            "ahead).",
            labels=["field"],
        )
        for name, n in sorted(self.states().items()):
            states.add_metric([name], n)
        yield states
