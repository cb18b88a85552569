"""The composition root: one cloud's parts, built in dependency order (``build_cloud``).

Every part is handed what it needs when it is made; nothing is set on it
afterwards. The order is the dependency graph, bottom up::

    store   router session -> robot link
      \\          |
       RobotRoutes (which robot works for which request)
            |
           Home (this cloud's robots, lent to others)  -> Zenoh overlay (answers with Home)
            |                                              |
           FederationView (this cloud and the others) <----'
            |
           RequestService (the requests' actors)
            |
           MissionService (the missions' runners; its book, made first, tells Home
            |              which robots missions keep and which missions are known)
           LoanReconciler (loans kept true both ways; told of ended loans by the service)

``create_app`` enters it in its lifespan; ``robocloud iaas``, ``make run`` and
the tests all come through ``create_app``. Tests may hand in a store, a robot
link or a selector of their own; without a link there is no router, so no
overlay either (one cloud alone).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from dataclasses import dataclass

from robocloud.federation.home import Home
from robocloud.federation.overlay import ZenohOverlay
from robocloud.federation.reconcile import LoanReconciler, reconcile_period
from robocloud.federation.view import FederationView
from robocloud.fleet.link import RobotLink
from robocloud.iaas.actor import Selector
from robocloud.iaas.capabilities import KnownCapabilities
from robocloud.iaas.config import Settings
from robocloud.iaas.elsewhere import Elsewhere
from robocloud.iaas.metrics import IaasMetrics
from robocloud.iaas.missions.book import MissionBook
from robocloud.iaas.missions.service import MissionService, Origins
from robocloud.iaas.routes import RobotRoutes
from robocloud.iaas.service import RequestService
from robocloud.storage import RequestStore, open_store


@dataclass(frozen=True)
class Cloud:
    """The running parts of one cloud's IaaS."""

    settings: Settings
    store: RequestStore
    link: RobotLink
    routes: RobotRoutes
    home: Home
    overlay: ZenohOverlay | None
    view: FederationView
    service: RequestService
    reconciler: LoanReconciler
    capabilities: KnownCapabilities  # every capability the federation announced
    elsewhere: Elsewhere  # which other cloud holds a request
    missions: MissionService


@contextlib.asynccontextmanager
async def build_cloud(
    settings: Settings,
    metrics: IaasMetrics,
    store: RequestStore | None = None,
    link: RobotLink | None = None,
    selector: Selector | None = None,
) -> AsyncIterator[Cloud]:
    """Open and start the cloud's parts; on exit, stop and close them in reverse order."""
    async with contextlib.AsyncExitStack() as stack:
        if store is None:
            store = open_store(settings.store_url)
            stack.callback(store.close)
        session = None
        if link is None:
            from robocloud.fleet import ZenohRobotLink, open_router

            security = settings.overlay_security
            session = open_router(
                list(settings.zenoh_listen),
                list(settings.zenoh_peers),
                security.for_cloud(settings.cloud, settings.trusted) if security else None,
            )
            stack.callback(session.close)
            link = ZenohRobotLink(
                session,
                settings.cloud,
                offline_after=settings.offline_after,
                command_timeout=settings.ack_timeout,
                forget_after=settings.forget_after,
                max_fleet=settings.max_fleet,
                fronts=dict(security.gateways) if security else None,
            )
            stack.callback(link.close)
        metrics.observe_states_refused(link.state_refusals)
        routes = RobotRoutes(settings.set_aside_for)
        book = MissionBook(store)
        home = Home(
            settings.cloud,
            store,
            link,
            settings.trusted,
            api=f"http://{settings.host}:{settings.port}",
            lease_max=settings.lease_max,
            origin_deadline=settings.origin_deadline,
            lend_share=settings.lend_share,
            coalition_of=routes.robots_of,
            missions=book.status,
            kept=routes.kept_by_missions,
            set_aside=routes.aside,
        )
        overlay = None
        if session is not None and settings.federation:
            overlay = ZenohOverlay(
                session, settings.cloud, home, offline_after=settings.offline_after
            )
            stack.callback(overlay.close)
            metrics.observe_refusals(overlay.presence.refusals, home.bound_refusals)
        view = FederationView(settings.cloud, store, link, overlay, settings.gather_timeout)
        service = RequestService(
            settings,
            store,
            view,
            metrics=metrics,
            selector=selector,
            routes=routes,
            home_info=home.info,
            lent_for=home.lent_for,
        )
        missions = MissionService(
            settings.cloud,
            book,
            store,
            view,
            routes,
            service.rules,
            service.blocking,
            service.clock,
        )
        reconciler = LoanReconciler(home, overlay, Origins(service, missions), view.lenders)
        metrics.observe_states(settings.cloud, service.robot_statuses, service.active_states)
        await service.start()
        stack.push_async_callback(service.stop)
        await missions.start()
        stack.push_async_callback(missions.stop)
        reconciling = asyncio.ensure_future(
            reconciler.reconcile_forever(reconcile_period(settings.origin_deadline))
        )
        stack.callback(reconciling.cancel)
        yield Cloud(
            settings,
            store,
            link,
            routes,
            home,
            overlay,
            view,
            service,
            reconciler,
            KnownCapabilities(home.announced, link.robots, overlay),
            Elsewhere(overlay),
            missions,
        )
