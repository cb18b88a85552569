"""Missions as an IaaS gives them (MISSION_API.md's JSON), planned simply, for the page's tests.

``plan`` shares the tasks out greedily (in an order that keeps the
precedence, each task to the robots that can be there first), so the page
is shown a true plan of the mission it sent: every time follows from the
robots' positions and speeds, none is made up. ``advance`` moves a mission to
a moment of its plan (task and robot states, progress) and ``replan`` makes a
new version for the tasks not started, without one robot, as a test's IaaS
would after that robot failed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

DEFAULT_DURATION = 60.0
FINAL = ("completed", "rejected", "failed", "canceled")


def _distance(a: Sequence[float], b: Sequence[float]) -> float:
    return math.hypot(a[0] - b[0], a[1] - b[1])


def _order(tasks: list[Mapping[str, Any]], precedence: list[list[str]]) -> list[Mapping[str, Any]]:
    """The tasks in the order given, each after the tasks it must follow."""
    done: set[str] = set()
    out: list[Mapping[str, Any]] = []
    while len(out) < len(tasks):
        ready = [t for t in tasks if t["id"] not in done
                 and all(b in done for b, a in precedence if a == t["id"])]
        if not ready:
            raise ValueError("the precedence has a cycle")
        out.append(ready[0])
        done.add(ready[0]["id"])
    return out


def _needs(task: Mapping[str, Any]) -> dict[str, int]:
    return {**task.get("actuating", {}), **task.get("sensing", {})}


def plan(mission: Mapping[str, Any], robots: list[dict[str, Any]], *, after: float = 0.0,
         kept: Sequence[Mapping[str, Any]] = (),
         at: Mapping[str, tuple[Sequence[float], float]] | None = None) -> dict[str, Any]:
    """A plan of ``mission`` (its tasks not in ``kept``) for ``robots``, times from 0.

    ``at`` says where each robot is free and from when (a re-plan); tasks
    start at ``after`` at the soonest.
    """
    tasks = [t for t in mission["tasks"] if t["id"] not in {k["id"] for k in kept}]
    precedence = [list(p) for p in mission.get("precedence", [])]
    ends = {k["id"]: k["end"] for k in kept}
    state = {r["id"]: (list(at[r["id"]][0]) if at else list(r["position"]),
                       at[r["id"]][1] if at else 0.0) for r in robots}
    speed = {r["id"]: float(r.get("speed", 1.0)) for r in robots}
    legs: dict[str, list[dict[str, Any]]] = {r["id"]: [] for r in robots}
    planned = [dict(k) for k in kept]
    for task in _order(tasks, [p for p in precedence if p[0] not in ends]):
        members: list[str] = []
        for capability, count in _needs(task).items():
            able = [r for r in robots if capability in r["capabilities"]
                    and r["id"] not in members]
            able.sort(key=lambda r: state[r["id"]][1]
                      + _distance(state[r["id"]][0], task["location"]) / speed[r["id"]])
            if len(able) < count:
                raise ValueError(f"{task['id']} needs {count} robots bringing {capability!r}, "
                                 f"and {len(able)} do")
            members += [r["id"] for r in able[:count]]
        arrive = {m: state[m][1] + _distance(state[m][0], task["location"]) / speed[m]
                  for m in members}
        start = max([after, *arrive.values(),
                     *(ends[b] for b, a in precedence if a == task["id"])])
        end = start + float(task.get("duration") or DEFAULT_DURATION)
        ends[task["id"]] = end
        for m in members:
            legs[m].append({"task": task["id"], "depart": round(state[m][1], 3),
                            "arrive": round(arrive[m], 3), "start": round(start, 3),
                            "end": round(end, 3)})
            state[m] = (list(task["location"]), end)
        planned.append({"id": task["id"], "location": list(task["location"]), "robots": members,
                        "start": round(start, 3), "end": round(end, 3), "state": "pending",
                        "progress": 0.0})
    routes = []
    for r in robots:
        if not legs[r["id"]]:
            continue
        end_place = list(mission.get("end") or state[r["id"]][0])
        home = state[r["id"]][1] + _distance(state[r["id"]][0], end_place) / speed[r["id"]]
        routes.append({"id": r["id"], "cloud": r["cloud"], "from": list(r["position"]),
                       "legs": legs[r["id"]], "end": end_place, "home_at": round(home, 3),
                       "state": "assigned"})
    makespan = max(r["home_at"] for r in routes)
    # A bound no plan beats: the longest of reaching a task, doing it and reaching the end.
    bound = max(min(_distance(r["position"], t["location"]) / speed[r["id"]] for r in robots)
                + float(t.get("duration") or DEFAULT_DURATION) for t in tasks) if tasks else 0.0
    bound = min(bound, makespan)
    return {"version": 1, "planned_at": 0.0, "makespan": round(makespan, 3),
            "lower_bound": round(bound, 3), "gap": round((makespan - bound) / makespan, 4),
            "optimal": False, "tasks": planned, "robots": routes}


def advance(mission: dict[str, Any], t: float) -> None:
    """The mission as it is ``t`` seconds after its start: states and progress."""
    the_plan = mission["plan"]
    for task in the_plan["tasks"]:
        if task["state"] in ("failed", "canceled"):
            continue
        legs = [leg for r in the_plan["robots"] for leg in r["legs"] if leg["task"] == task["id"]]
        if t >= task["end"]:
            task["state"], task["progress"] = "done", 1.0
        elif t >= task["start"]:
            task["state"] = "work"
            task["progress"] = round((t - task["start"]) / (task["end"] - task["start"]), 3)
        elif any(t >= leg["arrive"] for leg in legs):
            task["state"] = "waiting"
        elif any(t >= leg["depart"] for leg in legs):
            task["state"] = "travel"
    for robot in the_plan["robots"]:
        if robot["state"] == "failed":
            continue
        robot["state"] = "assigned" if t < robot["legs"][0]["depart"] else "released"
        for leg in robot["legs"]:
            if leg["depart"] <= t < leg["arrive"]:
                robot["state"] = "travel"
            elif leg["arrive"] <= t < leg["start"]:
                robot["state"] = "waiting"
            elif leg["start"] <= t < leg["end"]:
                robot["state"] = "working"
        if robot["legs"][-1]["end"] <= t < robot["home_at"]:
            robot["state"] = "returning"
    tasks = the_plan["tasks"]
    mission["progress"] = round(sum(task["progress"] for task in tasks) / len(tasks), 3)
    if all(task["state"] == "done" for task in tasks) and t >= the_plan["makespan"]:
        mission["state"] = "completed"
        mission["history"].append({"at": mission["started_at"] + t, "state": "completed",
                                   "note": "every task done, every robot home"})


def replan(mission: dict[str, Any], robots: list[dict[str, Any]], t: float, without: str
           ) -> None:
    """Version + 1: the tasks not started, planned again at ``t`` without robot ``without``."""
    old = mission["plan"]
    kept = [task for task in old["tasks"] if task["start"] <= t]
    at: dict[str, tuple[Sequence[float], float]] = {}
    for robot in robots:
        route = next((r for r in old["robots"] if r["id"] == robot["id"]), None)
        done = [leg for leg in (route["legs"] if route else []) if leg["start"] <= t]
        place = (next(k["location"] for k in kept if k["id"] == done[-1]["task"]) if done
                 else robot["position"])
        at[robot["id"]] = (place, max(t, done[-1]["end"]) if done else t)
    others = [r for r in robots if r["id"] != without]
    new = plan(mission["mission"], others, after=t, kept=kept, at=at)
    for route in new["robots"]:
        before = next((r for r in old["robots"] if r["id"] == route["id"]), None)
        if before:
            route["from"] = before["from"]
            route["legs"] = [leg for leg in before["legs"] if leg["start"] <= t] + [
                leg for leg in route["legs"] if leg["task"] not in {k["id"] for k in kept}]
    failed = next((r for r in old["robots"] if r["id"] == without), None)
    if failed:
        new["robots"].append({**failed, "state": "failed",
                              "legs": [leg for leg in failed["legs"] if leg["start"] <= t]
                              or failed["legs"][:1]})
    new["version"] = old["version"] + 1
    new["planned_at"] = t
    mission["plan"] = new
    mission["history"].append({"at": mission["started_at"] + t, "state": "underway",
                               "note": f"re-planned (version {new['version']}): robot "
                                       f"{without} failed"})
