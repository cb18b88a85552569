"""What the wildfire server checks of a task or a mission before an IaaS sees it.

Only what this application knows better than the IaaS: its forest (a fire,
or a mission's end place, outside it is refused) and its fleet (a capability
no robot of the federation has). Anything else (a missing field, a wrong
type) is left to the IaaS, whose sentence comes back as it is. Each refusal
is an ``IaasError`` of 422 naming the field, as the IaaS's own do.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

from robocloud.wildfire.iaas_client import IaasError
from robocloud.wildfire.live import LiveModel


def check_task(body: bytes, model: LiveModel) -> None:
    """What this application knows better than the IaaS: its forest and its fleet.

    Anything else (a missing field, a wrong type) is left to the IaaS, whose
    sentence comes back as it is.
    """
    task = _json(body, "a task")
    if isinstance(task, Mapping):
        _check_place(task.get("location"), "location", "fire", model)
        _check_needs(task, "", model)


def check_mission(body: bytes, model: LiveModel) -> None:
    """A mission's fires and end place, each as a task's (``check_task``)."""
    mission = _json(body, "a mission")
    if not isinstance(mission, Mapping):
        return
    tasks = mission.get("tasks")
    for i, task in enumerate(tasks if isinstance(tasks, list) else []):
        if isinstance(task, Mapping):
            _check_place(task.get("location"), f"tasks[{i}].location", "fire", model)
            _check_needs(task, f"tasks[{i}].", model)
    _check_place(mission.get("end"), "end", "end place", model)


def _json(body: bytes, what: str) -> Any:
    try:
        return json.loads(body)
    except ValueError:
        raise IaasError(422, f"the body is not JSON: send {what} as a JSON object.") from None


def _check_place(location: Any, field: str, what: str, model: LiveModel) -> None:
    if (isinstance(location, list) and len(location) == 2
            and all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                    for v in location)):
        refusal = model.settings.forest.refusal(float(location[0]), float(location[1]), what)
        if refusal:
            raise IaasError(422, f"{field}: {refusal}")


def _check_needs(task: Mapping[str, Any], prefix: str, model: LiveModel) -> None:
    known = model.known_capabilities()
    if not known:
        return  # the fleet is not heard yet: the IaaS decides
    for kind in ("actuating", "sensing"):
        wanted = task.get(kind)
        if not isinstance(wanted, Mapping):
            continue
        for name in wanted:
            if name not in known:
                offered = ", ".join(sorted(known)[:20])
                raise IaasError(422, f"{prefix}{kind}.{str(name)[:60]}: no robot of the "
                                     f"federation has the capability {str(name)[:60]!r}; the "
                                     f"fleet has {offered}.")
