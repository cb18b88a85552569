// The Pareto front of a request: time against cost, the number of robots as
// the marker's size, the chosen coalition marked and labelled with its
// priority, and where the two other priorities would have chosen (the
// request's "choices", when its IaaS gives them). After a robot is replaced,
// the coalition now at work is marked too ("now"), where its time and cost are.
// The axes start and end on a tick, so every point lies within the labels.
// Inline SVG.

import { fmtNumber, niceAxis, PRIORITY, svg, tickDigits } from "./util.js";

const W = 380;
const H = 190;
const M = { left: 48, right: 14, top: 14, bottom: 34 };

export function radiusFor(size) {
  return Math.min(16, 4 + 2.4 * (Math.max(1, size) - 1));
}

function near(a, b) {
  return Math.abs(a - b) <= Math.max(1e-6, 1e-9 * Math.max(Math.abs(a), Math.abs(b)));
}

function sameRobots(a, b) {
  const x = [...a].sort();
  const y = [...b].sort();
  return x.length === y.length && x.every((r, i) => r === y[i]);
}

// The member chosen at selection: the one the history's dispatch named (a
// replacement changes the coalition, not what was chosen), else the coalition
// itself, else the one at the request's time and cost.
export function isChosen(member, request) {
  const dispatched = (request.history || []).find((h) => h.kind === "state" && h.state === "dispatched");
  const named = dispatched && /robots?: (.+)$/.exec(dispatched.detail || "");
  if (named) return sameRobots(member.robots, named[1].split(",").map((r) => r.trim()));
  const coalition = (request.coalition || []).map((a) => a.robot);
  if (coalition.length) return sameRobots(member.robots, coalition);
  return request.time !== null && request.cost !== null
    && near(member.time, request.time) && near(member.cost, request.cost);
}

export function drawFront(request, { currency = "" } = {}) {
  const front = request.pareto || [];
  const coalition = (request.coalition || []).map((a) => a.robot);
  // The coalition at work, when a replacement made it another than the chosen one:
  // on the front if it is a member, else where the request's time and cost put it.
  const chosenMember = front.find((m) => isChosen(m, request));
  let current = null;
  if (coalition.length && !(chosenMember && sameRobots(chosenMember.robots, coalition))) {
    const member = front.find((m) => sameRobots(m.robots, coalition));
    if (member) current = member;
    else if (Number.isFinite(request.time) && Number.isFinite(request.cost)) {
      current = { time: request.time, cost: request.cost, size: coalition.length };
    }
  }
  const plot = svg("svg", {
    viewBox: `0 0 ${W} ${H}`, role: "img", class: "front-plot",
    "aria-label": `Pareto front: ${front.length} coalition${front.length === 1 ? "" : "s"}, time against cost`,
  });
  const points = current && !front.includes(current) ? [...front, current] : front;
  const timeAxis = niceAxis(points.map((m) => m.time));
  const costAxis = niceAxis(points.map((m) => m.cost));
  const [t0, t1, c0, c1] = [timeAxis.lo, timeAxis.hi, costAxis.lo, costAxis.hi];
  const x = (t) => M.left + ((t - t0) / (t1 - t0)) * (W - M.left - M.right);
  const y = (c) => H - M.bottom - ((c - c0) / (c1 - c0)) * (H - M.top - M.bottom);

  const axis = svg("g", { class: "axis" });
  const timeTicks = timeAxis.ticks;
  const timeDigits = tickDigits(timeTicks);
  const costTicks = costAxis.ticks;
  const costDigits = tickDigits(costTicks);
  for (const t of timeTicks) {
    axis.append(svg("line", { class: "gridline", x1: x(t), x2: x(t), y1: M.top, y2: H - M.bottom }));
    axis.append(svg("text", { class: "tick-x", x: x(t), y: H - M.bottom + 13, "text-anchor": "middle", text: fmtNumber(t, timeDigits) }));
  }
  for (const c of costTicks) {
    axis.append(svg("line", { class: "gridline", x1: M.left, x2: W - M.right, y1: y(c), y2: y(c) }));
    axis.append(svg("text", { class: "tick-y", x: M.left - 5, y: y(c) + 3.5, "text-anchor": "end", text: fmtNumber(c, costDigits) }));
  }
  axis.append(svg("path", { d: `M${M.left} ${M.top} V${H - M.bottom} H${W - M.right}`, fill: "none" }));
  axis.append(svg("text", { class: "axis-title", x: (M.left + W - M.right) / 2, y: H - 4, "text-anchor": "middle", text: "time (robot seconds)" }));
  axis.append(svg("text", { class: "axis-title", x: 11, y: (M.top + H - M.bottom) / 2, "text-anchor": "middle",
    transform: `rotate(-90 11 ${(M.top + H - M.bottom) / 2})`, text: currency ? `cost (${currency})` : "cost" }));
  plot.append(axis);

  // The biggest first, so a small coalition is never hidden under a big one.
  const members = [...front].filter((m) => m !== current).sort((a, b) => b.size - a.size);
  let chosenPoint = null;
  for (const member of members) {
    const chosen = isChosen(member, request);
    const point = svg("circle", {
      class: chosen ? "point chosen" : "point", cx: x(member.time).toFixed(1), cy: y(member.cost).toFixed(1),
      r: radiusFor(member.size), "data-size": member.size, "data-time": member.time, "data-cost": member.cost,
    }, svg("title", { text: `${member.size} robot${member.size === 1 ? "" : "s"} (${member.robots.join(", ")}): `
      + `time ${fmtNumber(member.time)} robot s, cost ${fmtNumber(member.cost, 2)} ${currency}${chosen ? ", chosen" : ""}` }));
    plot.append(point);
    if (chosen) chosenPoint = { member, cx: x(member.time), cy: y(member.cost) };
  }
  const labels = new Labels();
  const priority = request.task && request.task.priority;
  const choices = choicesOf(request, front);
  if (chosenPoint) {
    const { member, cx, cy } = chosenPoint;
    const r = radiusFor(member.size) + 4;
    plot.append(svg("circle", { class: "chosen-ring", cx, cy, r }));
    const also = (choices.get(front.indexOf(member)) || []).filter((p) => p !== priority);
    const text = `chosen${priority ? ` (${PRIORITY[priority] || priority})` : ""}${also.length ? `, also ${also.map((p) => PRIORITY[p]).join(", ")}` : ""}`;
    plot.append(labels.place(cx, cy, r, text, "chosen-label"));
  }
  // Where the other priorities would have chosen: a dashed diamond and their names.
  for (const [index, names] of choices) {
    const member = front[index];
    if (!member || (chosenPoint && chosenPoint.member === member)) continue;
    const others = names.filter((p) => p !== priority);
    if (!others.length) continue;
    const cx = x(member.time);
    const cy = y(member.cost);
    const r = radiusFor(member.size) + 5;
    plot.append(svg("path", { class: "alt-choice", d: `M${cx} ${cy - r} L${cx + r} ${cy} L${cx} ${cy + r} L${cx - r} ${cy} Z`,
      "data-priorities": others.join(" "), "data-index": index }));
    plot.append(labels.place(cx, cy, r, `${others.map((p) => PRIORITY[p]).join(", ")} would choose`, "alt-label"));
  }
  if (current) {
    const cx = x(current.time);
    const cy = y(current.cost);
    plot.append(svg("rect", { class: "point current", x: cx - 6, y: cy - 6, width: 12, height: 12,
      "data-time": current.time, "data-cost": current.cost, "data-size": current.size },
    svg("title", { text: `now, after a replacement: ${current.size} robots, time ${fmtNumber(current.time)} robot s, cost ${fmtNumber(current.cost, 2)} ${currency}` })));
    plot.append(labels.place(cx, cy, 8, "now", "current-label"));
  }
  return plot;
}

// Member index -> the priorities that would choose it, from the request's
// "choices" ({"balanced": i, "time": j, "cost": k}); empty when not given.
export function choicesOf(request, front) {
  const out = new Map();
  const choices = request.choices;
  if (!choices || typeof choices !== "object") return out;
  for (const name of ["balanced", "time", "cost"]) {
    const index = choices[name];
    if (!Number.isInteger(index) || index < 0 || index >= front.length) continue;
    if (!out.has(index)) out.set(index, []);
    out.get(index).push(name);
  }
  return out;
}

// Labels beside their points, moved down (then up) until they overlap no other.
class Labels {
  constructor() {
    this.boxes = [];
  }

  place(cx, cy, r, text, cls) {
    const width = text.length * 5.6;
    const right = cx + r + 4 + width <= W - 2;
    const x0 = right ? cx + r + 4 : cx - r - 4 - width;
    let y = cy + 4;
    for (const dy of [0, 13, -13, 26, -26, 39]) {
      const box = { x0, x1: x0 + width, y0: cy + 4 + dy - 10, y1: cy + 4 + dy + 2 };
      if (box.y0 >= 0 && box.y1 <= H && !this.boxes.some((b) => b.x0 < box.x1 && box.x0 < b.x1 && b.y0 < box.y1 && box.y0 < b.y1)) {
        y = cy + 4 + dy;
        this.boxes.push(box);
        break;
      }
    }
    return svg("text", { class: cls, x: right ? cx + r + 4 : cx - r - 4, y, "text-anchor": right ? "start" : "end", text });
  }
}
