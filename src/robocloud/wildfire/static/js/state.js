// REQUEST STATE: the selected request as its IaaS gives it (state, reason,
// limits, the coalition's time and cost, the Pareto front, the coalition, the
// history), with its elapsed time, its ETA and its robots' progress kept live
// from the pushed fleet between two reads.

import { drawFront } from "./front.js";
import { elapsed } from "./tables.js";
import {
  cloudColour, el, FINAL_STATES, fmtClock, fmtDuration, fmtNumber, fmtPoint, humanize, PRIORITY, sentence,
} from "./util.js";

export function needsText(needs) {
  return Object.entries(needs || {}).map(([name, count]) => `${name}×${count}`).join(", ");
}

export function requestName(request) {
  return request.label ? `“${request.label}” (${request.id})` : request.id;
}

export class StatePanel {
  constructor(body, { live }) {
    this.body = body;
    this.live = live;
    this.request = null;
    this.stats = {};
    this.bars = new Map();   // robot id -> {bar, fill, phase}
  }

  currency() {
    return (this.live.config && this.live.config.currency) || "";
  }

  money(value) {
    return value === null || value === undefined ? "–" : `${fmtNumber(value, 2)} ${this.currency()}`;
  }

  // A robot time (seconds on the robots' clock), and what it is in real time.
  robotTime(seconds) {
    if (!Number.isFinite(seconds)) return ["–", ""];
    const scale = this.live.timeScale();
    return [fmtDuration(seconds), scale === 1 ? "" : `${fmtDuration(seconds / scale)} real`];
  }

  show(request) {
    this.request = request;
    const same = this.request && this.shownId === request.id;
    const kept = same ? this.body.querySelector("#state-more")?.scrollTop || 0 : 0;
    this.shownId = request.id;
    this.body.replaceChildren(...this.view(request));
    const scroller = this.body.querySelector("#state-more");
    if (scroller) scroller.scrollTop = kept;
    // The newest step in sight when the history is longer than its box.
    const box = this.body.querySelector("#history-box");
    if (box) box.scrollTop = box.scrollHeight;
    this.tick();
  }

  view(request) {
    const parts = [];
    parts.push(el("div", { class: "state-head", id: "state-head", "data-request": request.id, "data-state": request.state },
      el("span", { class: "badge", "data-state": request.state, id: "state-badge", text: request.state }),
      el("span", { class: "rid", text: request.id }),
      request.label ? el("span", { class: "label", text: request.label }) : null,
      request.held_by ? el("span", { class: "held", text: `at ${request.held_by}` }) : null));
    const task = request.task || {};
    const needs = needsText({ ...(task.actuating || {}), ...(task.sensing || {}) });
    const [maxTime] = this.robotTime(task.max_time);
    const more = [];   // below the state, the ETA and the history, scrolled in a short window
    // What was asked: below the coalition and the front, which matter more while it runs.
    const taskLine = el("p", { class: "muted task-line",
      text: `Fire at ${fmtPoint(task.location)} · ${needs} · at most ${fmtNumber(task.max_robots)} robots, `
        + `${this.money(task.max_cost)}, ${maxTime} robot time · battery ≥ ${fmtNumber(task.min_battery)}% · `
        + `${PRIORITY[task.priority] || task.priority} · ${task.execution}` });
    if (request.reason) parts.push(el("p", { class: "reason", id: "state-reason", text: sentence(humanize(request.reason)) }));

    const coalition = request.coalition || [];
    const [time, timeReal] = this.robotTime(request.time);
    this.stats = {
      elapsed: el("div", { class: "v", id: "stat-elapsed" }),
      eta: el("div", { class: "v", id: "stat-eta" }),
    };
    parts.push(el("div", { class: "stats" },
      statNode("ETA", this.stats.eta, "real time"),
      statNode("Elapsed", this.stats.elapsed, "real time"),
      stat("Robots", coalition.length ? fmtNumber(coalition.length) : "–", "", "stat-robots"),
      stat("Time (robot clock)", time, timeReal, "stat-time"),
      stat("Cost", this.money(request.cost), "", "stat-cost"),
      stat("Selection", request.optimizer ? request.optimizer : "–",
        request.selection_ms !== null && request.selection_ms !== undefined ? `${fmtNumber(request.selection_ms, 1)} ms` : "", "stat-selection")));

    const front = request.pareto || [];
    const frontBox = el("div", { class: "front", id: "front" },
      el("h3", { class: "subhead" }, el("span", { text: "Pareto front" }),
        el("span", { class: "hint", text: front.length ? `${front.length} coalition${front.length === 1 ? "" : "s"} · marker size = robots` : "" })));
    if (front.length) frontBox.append(drawFront(request, { currency: this.currency() }));
    else frontBox.append(el("p", { class: "muted", text: emptyFront(request.state) }));

    this.bars = new Map();
    if (coalition.length) {
      const rows = coalition.map((a) => {
        const swatch = el("span", { class: "swatch", "aria-hidden": "true" });
        swatch.style.background = cloudColour(a.cloud);
        const fill = el("div", { class: "fill" });
        const phase = el("span", { class: "phase" });
        // The words above the bar: "pending", "travel · 1 min 05 s", "canceled" are read whole.
        const bar = el("div", { class: "progress", role: "progressbar", "aria-valuemin": 0, "aria-valuemax": 100 },
          phase, el("div", { class: "track" }, fill));
        this.bars.set(a.robot, { bar, fill, phase, assignment: a });
        const [t] = this.robotTime(a.time);
        return el("tr", { "data-robot": a.robot },
          el("td", {}, el("span", { class: "robot-id" }, swatch, a.robot), el("span", { class: "cloud", text: a.cloud })),
          el("td", { text: a.capabilities.join(", ") }),
          el("td", { class: "num", text: t }),
          el("td", { class: "num", text: fmtNumber(a.cost, 2) }),
          el("td", {}, bar));
      });
      more.push(el("div", { class: "coalition-box" },
        el("h3", { class: "subhead" }, el("span", { text: "Coalition" }), el("span", { class: "hint", text: `highlighted on the map · time in robot time, cost in ${this.currency()}` })),
        el("div", { class: "table-scroll" }, el("table", { class: "coalition", id: "coalition" },
          el("thead", {}, el("tr", {}, el("th", { text: "Robot" }), el("th", { text: "Capabilities" }),
            el("th", { class: "num", text: "Time" }), el("th", { class: "num", text: "Cost" }), el("th", { class: "progress-head", text: "Progress" }))),
          el("tbody", {}, ...rows)))));
    }
    more.push(frontBox, taskLine);
    parts.push(el("div", { class: "state-more", id: "state-more" }, ...more));

    parts.push(el("div", { class: "history-box", id: "history-box" },
      el("h3", { class: "subhead" }, el("span", { text: "History" }), el("span", { class: "hint", text: "real time" })),
      el("ol", { class: "history", id: "history" }, ...(request.history || []).map((h) => el("li", { "data-state": h.state, "data-kind": h.kind },
        el("time", { datetime: h.at, text: fmtClock(h.at) }),
        h.kind === "state" ? el("span", { class: "badge", "data-state": h.state, text: h.state }) : el("span", { class: "event", text: "event" }),
        el("span", { class: "detail", text: humanize(h.detail || "") }))))));
    return parts;
  }

  // Every second: elapsed, ETA and progress, from the live fleet.
  tick() {
    const request = this.request;
    if (!request) return;
    const summary = this.live.requests.get(request.id) || { ...request, robots: (request.coalition || []).map((a) => [a.robot, a.cloud, a.time, a.cost]) };
    const state = summary.state || request.state;
    if (this.stats.elapsed) this.stats.elapsed.textContent = fmtDuration(elapsed({ ...request, state }, this.live.now()));
    if (this.stats.eta) {
      const eta = this.live.requestEta({ ...summary, state });
      this.stats.eta.textContent = eta === null ? (FINAL_STATES.has(state) ? "–" : "…") : `≈ ${fmtDuration(eta)}`;
    }
    for (const [id, { bar, fill, phase, assignment }] of this.bars) {
      const robot = this.live.robots.get(id);
      let current = assignment.progress || { phase: "pending", progress: 0 };
      if (!FINAL_STATES.has(state) && robot && (robot.phase === "travel" || robot.phase === "work" || robot.phase === "done")) {
        current = { phase: robot.phase, progress: robot.progress ?? 0 };
      }
      const value = Math.max(0, Math.min(1, current.progress ?? 0));
      fill.style.width = `${(value * 100).toFixed(1)}%`;
      bar.dataset.phase = current.phase;
      bar.setAttribute("aria-valuenow", String(Math.round(value * 100)));
      bar.setAttribute("aria-label", `${id} ${current.phase}`);
      const eta = this.live.robotEta(robot, assignment.time);
      phase.textContent = current.phase === "travel" || current.phase === "work"
        ? `${current.phase}${eta === null ? "" : ` · ${fmtDuration(eta)}`}` : current.phase;
    }
  }
}

function stat(name, value, sub, id) {
  return el("div", { class: "stat" }, el("div", { class: "k", text: name }), el("div", { class: "v", id, text: value }),
    sub ? el("div", { class: "sub", text: sub }) : null);
}

function statNode(name, node, sub) {
  return el("div", { class: "stat" }, el("div", { class: "k", text: name }), node, el("div", { class: "sub", text: sub }));
}

function emptyFront(requestState) {
  if (requestState === "received" || requestState === "selecting") return "Selecting a coalition…";
  if (requestState === "rejected") return "No feasible coalition: nothing to plot.";
  return "No front was computed for this request.";
}
