"""The Wildfire Suppression Application: the thesis's PaaS application as a web page.

A small server (``robocloud wildfire --iaas URL``) serves the page and calls
the IaaS's HTTP API with the application's key, which the browser never sees.
The page places the fire, sends requests, follows their state, shows the
chosen coalition on the forest map with the Pareto front beside it, and
cancels requests: the thesis's three buttons, "Send a Request", "Get State
of a Request" and "Cancel a Request". Several fires may be sent as one
mission (planned jointly by the IaaS), followed as a Gantt chart of its plan
and routes on the map, and canceled.

It talks to the IaaS over HTTP only, as any other application would.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from robocloud.wildfire.app import create_wildfire_app

__all__ = ["create_wildfire_app"]


def __getattr__(name: str) -> object:
    # Lazily: building the ``robocloud`` parser imports the command module,
    # which should not pull in FastAPI.
    if name == "create_wildfire_app":
        from robocloud.wildfire.app import create_wildfire_app

        return create_wildfire_app
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
