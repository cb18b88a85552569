// The Gantt chart of a mission's plan: a row a robot, its route as time goes
// right. Each leg is the drive to a fire (a thin grey line), the wait there
// for the rest of the coalition (a dashed box: the gap between the leg's
// "arrive" and "start"), then the work (a bar in the fire's colour, darker
// over the part done); after its last fire, the drive to the end place. A
// line marks "now" and one the makespan. Times are the plan's: seconds from
// the mission's start, on the robots' clock. Inline SVG.

import { fmtDuration, fmtNumber, svg, ticks } from "./util.js";

const WIDTH = 760;          // unless the page says how wide the chart is, in pixels
const LABEL = 124;
const RIGHT = 12;
const TOP = 22;
const ROW = 26;
const BAR = 16;
const WAIT_MIN_S = 0.05;   // a shorter gap is rounding, not a wait

function title(text) {
  return svg("title", { text });
}

// Seconds or minutes, whichever reads better over `hi` seconds.
function axis(hi) {
  if (hi <= 600) return { unit: "s", per: 1, values: ticks(0, hi, 6) };
  const per = hi <= 36000 ? 60 : 3600;
  return { unit: per === 60 ? "min" : "h", per, values: ticks(0, hi / per, 6).map((v) => v * per) };
}

// `colourOf(taskId)` and `robotColour(robotId)` come from the page (the map uses them too);
// `now` is the plan's present (robot seconds since the start), or null.
export function drawGantt(mission, { colourOf, robotColour, now = null, width = WIDTH }) {
  const W = Math.max(360, Math.round(width));   // drawn at its size: its text stays legible
  const plan = mission.plan;
  const robots = plan.robots || [];
  const tasks = new Map((plan.tasks || []).map((t) => [t.id, t]));
  const last = Math.max(plan.makespan || 0, ...robots.map((r) => r.home_at || 0), ...(plan.tasks || []).map((t) => t.end || 0));
  const hi = Math.max(1, last, Number.isFinite(now) ? now : 0) * 1.03;
  const { unit, per, values } = axis(hi);
  const span = Math.max(hi, values[values.length - 1]);
  const x = (t) => LABEL + (Math.max(0, t) / span) * (W - LABEL - RIGHT);
  const height = TOP + robots.length * ROW + 6;
  const chart = svg("svg", {
    viewBox: `0 0 ${W} ${height}`, class: "gantt-chart", id: "gantt-chart", role: "img",
    "data-version": plan.version, "data-span": span.toFixed(3), "data-width": W,
    "aria-label": `Plan ${plan.version}: ${robots.length} robot${robots.length === 1 ? "" : "s"}, `
      + `${tasks.size} fire${tasks.size === 1 ? "" : "s"}, the last robot home after ${fmtDuration(plan.makespan)} robot time`,
  });
  const grid = svg("g", { class: "gantt-grid" });
  values.forEach((value, i) => {
    grid.append(svg("line", { x1: x(value), x2: x(value), y1: TOP - 4, y2: height - 4 }));
    const text = `${fmtNumber(value / per, per === 1 ? 0 : (values[1] - values[0]) / per < 1 ? 1 : 0)}${i === values.length - 1 ? ` ${unit}` : ""}`;
    grid.append(svg("text", { class: "tick", x: x(value), y: TOP - 8, "text-anchor": i === 0 ? "start" : "middle", text }));
  });
  chart.append(grid);

  robots.forEach((robot, row) => {
    const y = TOP + row * ROW;
    const mid = y + ROW / 2;
    const group = svg("g", { class: "gantt-row", "data-robot": robot.id, "data-state": robot.state || "" });
    group.append(svg("rect", { class: "row-bg", x: 0, y, width: W, height: ROW }));
    const swatch = svg("circle", { cx: 8, cy: mid, r: 5, class: "route-dot" });
    swatch.setAttribute("fill", robotColour(robot.id));
    group.append(swatch, svg("text", { class: "robot-name", x: 18, y: mid + 4, text: robot.id },
      title(`${robot.id} (${robot.cloud || "?"}): ${robot.state || "planned"}`)));
    if (robot.state) group.append(svg("text", { class: "robot-state", x: LABEL - 6, y: mid + 4, "text-anchor": "end", text: robot.state }));
    let place = 0;
    for (const leg of robot.legs || []) {
      const task = tasks.get(leg.task) || { state: "pending", progress: 0 };
      const colour = colourOf(leg.task);
      if (leg.arrive > leg.depart) {
        group.append(svg("rect", { class: "travel", "data-task": leg.task, x: x(leg.depart), y: mid - 2, width: Math.max(0.5, x(leg.arrive) - x(leg.depart)), height: 4 },
          title(`${robot.id} drives to ${leg.task}: ${fmtDuration(leg.arrive - leg.depart)} (from ${fmtDuration(leg.depart)} to ${fmtDuration(leg.arrive)})`)));
      }
      if (leg.start - leg.arrive > WAIT_MIN_S) {
        const wait = svg("rect", { class: "wait", "data-task": leg.task, "data-wait": (leg.start - leg.arrive).toFixed(3), x: x(leg.arrive), y: mid - BAR / 2 + 2, width: Math.max(0.5, x(leg.start) - x(leg.arrive)), height: BAR - 4 },
          title(`${robot.id} waits ${fmtDuration(leg.start - leg.arrive)} at ${leg.task} for the rest of its coalition`));
        wait.setAttribute("stroke", colour);
        group.append(wait);
      }
      const width = Math.max(1, x(leg.end) - x(leg.start));
      const bar = svg("rect", { class: "bar", "data-task": leg.task, "data-state": task.state, x: x(leg.start), y: mid - BAR / 2, width, height: BAR, rx: 3 },
        title(`${leg.task} (${task.state}${task.state === "work" ? ` ${Math.round((task.progress || 0) * 100)}%` : ""}): `
          + `${robot.id} works from ${fmtDuration(leg.start)} to ${fmtDuration(leg.end)}`));
      bar.setAttribute("fill", colour);
      group.append(bar);
      const done = task.state === "done" ? 1 : task.state === "work" ? Math.max(0, Math.min(1, task.progress || 0)) : 0;
      if (done > 0) group.append(svg("rect", { class: "bar-done", "data-task": leg.task, x: x(leg.start), y: mid - BAR / 2, width: width * done, height: BAR, rx: 3 }));
      if (width > 34) group.append(svg("text", { class: "bar-label", x: x(leg.start) + width / 2, y: mid + 4, "text-anchor": "middle", text: leg.task.replace(/^fire-/, "#") }));
      place = leg.end;
    }
    if (Number.isFinite(robot.home_at) && robot.home_at > place) {
      group.append(svg("rect", { class: "travel return", x: x(place), y: mid - 2, width: Math.max(0.5, x(robot.home_at) - x(place)), height: 4 },
        title(`${robot.id} drives to the end place: home at ${fmtDuration(robot.home_at)}`)));
    }
    chart.append(group);
  });

  if (Number.isFinite(plan.makespan)) {
    chart.append(svg("line", { class: "makespan", x1: x(plan.makespan), x2: x(plan.makespan), y1: TOP - 4, y2: height - 2 },
      title(`makespan: the last robot home at ${fmtDuration(plan.makespan)}`)));
  }
  if (Number.isFinite(now)) {
    const at = x(Math.min(now, span));
    chart.append(svg("g", { class: "now", id: "gantt-now", "data-at": now.toFixed(3) },
      svg("line", { x1: at, x2: at, y1: TOP - 4, y2: height - 2 }),
      svg("text", { x: at + 3, y: height - 6, text: "now" })));
  }
  return chart;
}

// Where plan time `t` is drawn, for tests and tooltips: the same scale as the chart.
export function ganttX(chart, t) {
  const span = Number(chart.dataset.span);
  return LABEL + (Math.max(0, t) / span) * (Number(chart.dataset.width) - LABEL - RIGHT);
}
