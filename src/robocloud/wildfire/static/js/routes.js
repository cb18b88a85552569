// A mission on the forest map: its fires, numbered in their colours (the
// Gantt chart's), its end place, and each robot's route through its fires
// to the end, in the robot's colour (its row's in the Gantt chart). While a
// mission is being built, its fires so far, dashed. Drawn again whenever the
// map is (zoom, pan), in the map's "mission" layer, under the robots.

import { taskColour } from "./mission.js";
import { fmtPoint, svg } from "./util.js";

// Colour-blind-friendly, darker than the fires' (Dark2), so a route is not read as a fire.
const ROUTE_COLOURS = ["#1B9E77", "#D95F02", "#7570B3", "#E7298A", "#66A61E", "#A6761D", "#E6AB02", "#666666"];

export class MissionOverlay {
  constructor(map) {
    this.map = map;
    this.layer = map.layers.mission;
    this.draft = { fires: [], end: null };
    this.mission = null;
    map.overlays.push(this);
  }

  // The mission being built (mission.js).
  setDraft(fires, end) {
    this.draft = { fires: fires.map((f) => ({ ...f })), end };
    this.draw();
  }

  // The mission followed (missionview.js), or null.
  setMission(mission) {
    this.mission = mission;
    this.draw();
  }

  tasks() {
    return (this.mission && this.mission.mission && this.mission.mission.tasks) || [];
  }

  colourOf(taskId) {
    const index = this.tasks().findIndex((t) => t.id === taskId);
    return taskColour(index < 0 ? 0 : index);
  }

  robotColour(robotId) {
    const robots = (this.mission && this.mission.plan && this.mission.plan.robots) || [];
    const index = robots.findIndex((r) => r.id === robotId);
    return ROUTE_COLOURS[Math.max(0, index) % ROUTE_COLOURS.length];
  }

  draw() {
    const layer = this.layer;
    layer.replaceChildren();
    const at = (point) => this.map.toScreen(point);
    const plan = this.mission && this.mission.plan;
    const places = new Map(this.tasks().map((t) => [t.id, t.location]));
    for (const task of (plan && plan.tasks) || []) if (Array.isArray(task.location)) places.set(task.id, task.location);
    if (plan) {
      for (const robot of plan.robots || []) {
        const points = [robot.from, ...(robot.legs || []).map((leg) => places.get(leg.task)), robot.end]
          .filter((p) => Array.isArray(p) && p.length === 2);
        if (points.length < 2) continue;
        const route = svg("polyline", { class: "route", "data-robot": robot.id, "data-state": robot.state || "",
          points: points.map((p) => at(p).map((v) => v.toFixed(1)).join(",")).join(" ") },
        svg("title", { text: `${robot.id}: ${(robot.legs || []).map((l) => l.task).join(" → ")}${robot.end ? " → end" : ""}` }));
        route.setAttribute("stroke", this.robotColour(robot.id));
        layer.append(route);
      }
    }
    const states = new Map(((plan && plan.tasks) || []).map((t) => [t.id, t.state]));
    this.tasks().forEach((task, i) => {
      layer.append(this.fireMark(task, i, states.get(task.id) || this.mission.state, false));
    });
    const end = this.mission && this.mission.mission && this.mission.mission.end;
    if (Array.isArray(end)) layer.append(this.endMark(end, false));
    this.draft.fires.forEach((fire, i) => layer.append(this.fireMark(fire, i, "draft", true)));
    if (this.draft.end) layer.append(this.endMark(this.draft.end, true));
  }

  fireMark(task, index, state, draft) {
    const [sx, sy] = this.map.toScreen(task.location);
    const mark = svg("g", { class: `mission-fire${draft ? " draft" : ""}`, "data-task": task.id, "data-state": state,
      transform: `translate(${sx.toFixed(1)} ${sy.toFixed(1)})` },
    svg("title", { text: `${task.id} at ${fmtPoint(task.location)}: ${state}` }),
    svg("circle", { r: 22 }),
    svg("text", { y: 8, "text-anchor": "middle", text: String(index + 1) }));
    mark.querySelector("circle").setAttribute("fill", taskColour(index));
    return mark;
  }

  endMark(point, draft) {
    const [sx, sy] = this.map.toScreen(point);
    return svg("g", { class: `mission-end${draft ? " draft" : ""}`, id: draft ? "mission-end-draft" : "mission-end",
      transform: `translate(${sx.toFixed(1)} ${sy.toFixed(1)})` },
    svg("title", { text: `end place ${fmtPoint(point)}: every robot of the plan ends here` }),
    svg("rect", { x: -18, y: -18, width: 36, height: 36, rx: 5 }),
    svg("text", { y: 8, "text-anchor": "middle", text: "E" }));
  }
}
