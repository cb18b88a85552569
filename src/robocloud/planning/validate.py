"""An independent check of a plan: every rule of the problem, from its statement.

Written from the MRTA-Benchmark README's rules (``shared/mrta/README.md``;
the dataset is Jakob Bichler's, TU Delft, DOI
10.4121/10e28ee0-9ad9-450d-8be7-6e6a91f2931f, CC BY 4.0) and docs/model.md's
mission, reading only the input and the printed plan: it uses nothing of the
planner (no ``Problem``, no timing code), so a rule the planner gets wrong is
not repeated here. Each function returns the broken rules as sentences; an
empty list means the plan is valid.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

# The dataset's numbers carry 8 significant digits (its README, "Numerical notes").
TOLERANCE = 1e-3


def check_mrta(
    instance: Mapping[str, Any], schedule: Mapping[str, Any], tolerance: float = TOLERANCE
) -> list[str]:
    """The README's rules 1 to 6 and its makespan, for a schedule in the dataset's format."""
    problems: list[str] = []
    q, r, durations, travel = instance["Q"], instance["R"], instance["T_e"], instance["T_t"]
    n, m = len(q), len(r) - 2
    end_depot = m + 1
    pairs = instance.get("precedence_constraints") or []
    if schedule.get("n_tasks") != m:
        problems.append(f"n_tasks is {schedule.get('n_tasks')}, not {m}")
    if schedule.get("n_robots") != n:
        problems.append(f"n_robots is {schedule.get('n_robots')}, not {n}")
    lists = schedule.get("robot_schedules", {})
    if sorted(lists) != sorted(str(i) for i in range(n)):
        problems.append("robot_schedules does not cover every robot exactly")
        return problems
    # task -> (start, end, members), from every member's list.
    seen: dict[int, tuple[float, float, list[int]]] = {}
    for i in range(n):
        entries = lists[str(i)]
        for entry in entries:
            k, start, end = entry["task"], entry["start_time"], entry["end_time"]
            if not 1 <= k <= m:
                problems.append(f"robot {i} lists task {k}, which is not a real task")
                continue
            if abs(end - start - durations[k]) > tolerance:
                problems.append(f"task {k} lasts {end - start:g}, not T_e = {durations[k]}")
            if k in seen:
                other_start, other_end, members = seen[k]
                if abs(other_start - start) > tolerance or abs(other_end - end) > tolerance:
                    problems.append(f"task {k}: its members do not start it together")
                if i in members:
                    problems.append(f"robot {i} lists task {k} twice")
                members.append(i)
            else:
                seen[k] = (start, end, [i])
        starts = [e["start_time"] for e in entries]
        if starts != sorted(starts):
            problems.append(f"robot {i}'s tasks are not in order of start time")
        # Rule 4: travel from the start depot, between tasks, one task at a time.
        place, free = 0, 0.0
        for entry in entries:
            k = entry["task"]
            if not 1 <= k <= m:
                continue
            if place and entry["start_time"] < free - tolerance:
                problems.append(
                    f"robot {i} works on tasks {place} and {k} at once "
                    f"({k} starts at {entry['start_time']:g}, {place} ends at {free:g})"
                )
            elif entry["start_time"] < free + travel[place][k] - tolerance:
                problems.append(
                    f"robot {i} cannot reach task {k} by {entry['start_time']:g} "
                    f"(it is free at {free:g} and needs {travel[place][k]:g} to get there)"
                )
            place, free = k, entry["end_time"]
    for k in range(1, m + 1):
        if k not in seen:
            problems.append(f"task {k} is not done")
            continue
        members = seen[k][2]
        needed = [s for s, flag in enumerate(r[k]) if flag]
        for s in needed:
            if not any(q[i][s] for i in members):
                problems.append(f"task {k} needs skill {s}, which no member has")
        for i in members:
            alone = [s for s in needed if q[i][s] and sum(q[j][s] for j in members) == 1]
            if not alone:
                problems.append(f"robot {i} is a passenger on task {k}: the others cover it")
    for j, k in pairs:
        if j in seen and k in seen and seen[k][0] < seen[j][1] - tolerance:
            problems.append(f"task {k} starts before task {j} has finished")
    arrivals = []
    for i in range(n):
        entries = lists[str(i)]
        if entries:
            last = entries[-1]
            arrivals.append(last["end_time"] + travel[last["task"]][end_depot])
        else:
            arrivals.append(travel[0][end_depot])
    makespan = max(arrivals)
    stated = schedule.get("makespan")
    if not isinstance(stated, int | float) or abs(stated - makespan) > tolerance:
        problems.append(f"makespan is stated as {stated}, but the last robot arrives at "
                        f"{makespan:g}")
    return problems


def check_mission(
    document: Mapping[str, Any], plan: Mapping[str, Any], tolerance: float = 1e-6
) -> list[str]:
    """docs/model.md's mission rules for ``robocloud plan``'s output on a mission."""
    problems: list[str] = []
    mission = document["mission"]
    robots = {r["id"]: r for r in document["robots"]}
    tasks = {t["id"]: t for t in mission["tasks"]}
    end = mission.get("end")
    execution = mission.get("execution", "parallel")
    done: dict[str, Mapping[str, Any]] = {}
    for entry in plan["tasks"]:
        if entry["id"] in done:
            problems.append(f"task {entry['id']} is planned twice")
        done[entry["id"]] = entry
    for name in tasks:
        if name not in done:
            problems.append(f"task {name} is not planned")
    cost = 0.0
    for name, entry in done.items():
        for robot_id in entry["robots"]:
            if robot_id not in plan["routes"]:
                problems.append(f"task {name}: {robot_id} has no route")
        task = tasks.get(name)
        if task is None:
            problems.append(f"{name} is no task of the mission")
            continue
        members = entry["robots"]
        required = {**task.get("sensing", {}), **task.get("actuating", {})}
        if len(set(members)) != len(members):
            problems.append(f"task {name} lists a robot twice")
        for robot_id in members:
            robot = robots.get(robot_id)
            if robot is None:
                problems.append(f"task {name}: {robot_id} is no robot of the input")
                continue
            if robot["status"] != "idle" or robot["battery"] < mission.get("min_battery", 0.0):
                problems.append(f"task {name}: {robot_id} is not idle or not charged enough")
        known = [robots[i] for i in members if i in robots]
        for capability, count in required.items():
            have = sum(1 for rb in known if capability in rb["capabilities"])
            if have < count:
                problems.append(f"task {name} needs {count} robots with {capability}, has {have}")
        for robot in known:
            others = [rb for rb in known if rb is not robot]
            if all(
                sum(1 for rb in others if c in rb["capabilities"]) >= n
                for c, n in required.items()
            ):
                problems.append(f"task {name}: {robot['id']} is a spare member")
        works = []
        for robot in known:
            used = [robot["capabilities"][c] for c in required if c in robot["capabilities"]]
            cost += sum(c["cost"] for c in used)
            if task.get("duration") is not None:
                works.append(task["duration"])
            elif used:
                times = [c["time"] for c in used]
                works.append(max(times) if execution == "parallel" else sum(times))
        if works and entry["end"] - entry["start"] < max(works) - tolerance:
            problems.append(f"task {name} ends before its slowest member is done")
    for before, after in mission.get("precedence", []):
        if before in done and after in done and (
            done[after]["start"] < done[before]["end"] - tolerance
        ):
            problems.append(f"task {after} starts before task {before} has finished")
    arrivals = []
    for robot_id, route in plan["routes"].items():
        robot = robots[robot_id]
        place: Sequence[float] = robot["position"]
        free = 0.0
        mine = sorted((n for n, e in done.items() if robot_id in e["robots"]),
                      key=lambda n: done[n]["start"])
        if [step["task"] for step in route] != mine:
            problems.append(f"{robot_id}'s route is not its tasks in order of start")
        distance = 0.0
        for step in route:
            entry = done.get(step["task"])
            if entry is None:
                continue
            location = tasks[step["task"]]["location"]
            leg = math.dist(place, location)
            distance += leg
            if entry["start"] < free + leg / robot["speed"] - tolerance:
                problems.append(f"{robot_id} cannot reach task {step['task']} by its start")
            if abs(step["start"] - entry["start"]) > tolerance:
                problems.append(f"{robot_id} does not start task {step['task']} with the others")
            if free > entry["start"] + tolerance:
                problems.append(f"{robot_id} works on two tasks at once")
            place, free = location, entry["end"]
        if route:
            leg = math.dist(place, end) if end is not None else 0.0
            distance += leg
            arrivals.append(free + leg / robot["speed"])
        cost += distance * robot["travel_cost_per_m"]
    makespan = max(arrivals, default=0.0)
    if abs(plan["makespan"] - makespan) > tolerance * max(1.0, makespan):
        problems.append(f"makespan is stated as {plan['makespan']}, but it is {makespan:g}")
    if abs(plan["cost"] - cost) > tolerance * max(1.0, cost):
        problems.append(f"cost is stated as {plan['cost']}, but it is {cost:g}")
    limit = mission.get("max_time")
    if limit is not None and makespan > limit + tolerance:
        problems.append(f"the makespan {makespan:g} is over max_time {limit:g}")
    return problems
