// MISSION: the mission followed, live. Its state, plan version, makespan,
// lower bound and gap, progress; the Gantt chart (gantt.js) with a "now"
// line; each fire's state and progress; the history (why a re-plan came);
// the routes on the map (routes.js); and its Cancel. The page follows the
// IaaS's event stream through the wildfire server
// (GET /api/missions/{id}/events: the mission now, then after each change,
// until it is final), reading it once first so the chart shows at once.

import { drawGantt } from "./gantt.js";
import { needsOf } from "./mission.js";
import { $, el, fmtClock, fmtDuration, fmtNumber, sentence } from "./util.js";

// A mission's final states (MISSION_API.md): nothing changes after them.
export const MISSION_FINAL = new Set(["completed", "rejected", "failed", "canceled"]);
const RETRY_S = 3;

function percent(value) {
  return Number.isFinite(value) ? `${fmtNumber(value * 100, value < 0.1 && value > 0 ? 1 : 0)}%` : "–";
}

export class MissionView {
  constructor({ api, live, overlay, onShow = () => {}, onState = () => {}, onMission = () => {} }) {
    this.api = api;
    this.live = live;
    this.overlay = overlay;
    this.onShow = onShow;          // a mission was chosen: the page brings its tab forward
    this.onState = onState;        // its state changed: the page says so
    this.onMission = onMission;    // every update, as the IaaS gives it
    this.mission = null;
    this.id = null;
    this.source = null;
    this.retry = null;
    this.known = new Map();        // id -> the mission as last listed or read
    $("mission-pick").addEventListener("change", () => { if ($("mission-pick").value) this.follow($("mission-pick").value); });
    $("mission-cancel").addEventListener("click", () => this.askCancel());
    $("mission-cancel-dialog").addEventListener("close", () => this.cancel());
    setInterval(() => this.tick(), 1000);
    // Drawn at the width it has: again when it is shown (a tab) or resized.
    let width = 0;
    new ResizeObserver(() => {
      const now = $("gantt").clientWidth;
      if (now && Math.abs(now - width) > 4 && this.mission) { width = now; this.drawChart(); }
    }).observe($("gantt"));
  }

  // What a robot working on request `requestId` works for, when it is a task of a
  // mission this page knows: "fire-2 of “three fires” (mis-…)"; else null. A
  // mission's task reaches a robot as "<mission id>.<n>", n from 1 in the order
  // of the mission's tasks (robocloud.domain.mission_ids).
  taskName(requestId) {
    const match = /^(mis-[a-z0-9]+)\.([1-9][0-9]*)$/.exec(requestId || "");
    const mission = match && this.known.get(match[1]);
    if (!mission) return null;
    const task = ((mission.mission && mission.mission.tasks) || [])[Number(match[2]) - 1];
    const name = mission.label ? `“${mission.label}” (${mission.id})` : mission.id;
    return `${task ? task.id : `task ${match[2]}`} of mission ${name}`;
  }

  async loadList() {
    const answer = await this.api.missions({ limit: 20 });
    if (!answer.ok) return;
    if (!answer.data.items.length && !this.id) $("mission-error").textContent = (answer.data.missing || []).map(sentence).join(" ");
    for (const mission of answer.data.items) if (!this.known.has(mission.id) || mission.id !== this.id) this.known.set(mission.id, mission);
    this.fillPick();
    if (!this.id && answer.data.items.length) this.follow(answer.data.items[0].id, false);
  }

  fillPick() {
    const missions = [...this.known.values()].sort((a, b) => b.created_at - a.created_at);
    const pick = $("mission-pick");
    pick.replaceChildren(...(missions.length ? missions : [null]).map((m) => (m
      ? el("option", { value: m.id, text: `${m.label ? `“${m.label}” ` : ""}${m.id} · ${m.state}` })
      : el("option", { value: "", text: "none yet" }))));
    pick.value = this.id || "";
  }

  // Follow mission `id`: read it, then its events until it is final.
  async follow(id, announce = true) {
    this.stop();
    this.id = id;
    this.mission = null;
    $("mission-error").textContent = "";
    const answer = await this.api.mission(id);
    if (id !== this.id) return;
    if (!answer.ok) {
      $("mission-error").textContent = sentence(answer.detail);
      this.retryLater();
      return;
    }
    this.show(answer.data, announce);
    if (!MISSION_FINAL.has(answer.data.state)) this.listen();
  }

  listen() {
    const id = this.id;
    const source = new EventSource(this.api.missionEvents(id));
    this.source = source;
    source.addEventListener("mission", (event) => {
      if (this.source !== source) return;
      $("mission-error").textContent = "";
      const mission = JSON.parse(event.data);
      this.show(mission, false);
      if (MISSION_FINAL.has(mission.state)) this.stop();
    });
    source.addEventListener("error", () => {
      if (this.source !== source) return;
      // An answer that is not a stream (the IaaS unreachable) ends the source: try again.
      if (source.readyState === EventSource.CLOSED) this.retryLater();
      else $("mission-error").textContent = "The mission's updates broke off; reconnecting…";
    });
  }

  retryLater() {
    this.stop(false);
    const id = this.id;
    $("mission-error").textContent = `${$("mission-error").textContent || "The mission's updates broke off."} Trying again in ${RETRY_S} s.`.trim();
    this.retry = setTimeout(() => { if (this.id === id) this.follow(id, false); }, RETRY_S * 1000);
  }

  stop(forget = true) {
    if (this.source) this.source.close();
    this.source = null;
    clearTimeout(this.retry);
    if (forget) this.retry = null;
  }

  show(mission, announce) {
    const before = this.mission;
    this.mission = mission;
    this.known.set(mission.id, mission);
    this.fillPick();
    const badge = $("mission-state");
    badge.hidden = false;
    badge.textContent = mission.state;
    badge.dataset.state = mission.state;
    $("mission-view").dataset.mission = mission.id;
    $("mission-view").dataset.state = mission.state;
    $("mission-cancel").disabled = MISSION_FINAL.has(mission.state);
    this.drawStats();
    this.drawTasks();
    this.drawHistory();
    this.drawChart();
    this.overlay.setMission(mission);
    this.onMission(mission);
    if (announce) this.onShow(mission);
    else if (before && before.id === mission.id && before.state !== mission.state) this.onState(mission);
  }

  // The plan's present, in robot seconds since the start; null when nothing runs.
  planNow() {
    const m = this.mission;
    if (!m || MISSION_FINAL.has(m.state) || !Number.isFinite(m.started_at)) return null;
    return Math.max(0, (this.live.now() - m.started_at) * this.live.timeScale());
  }

  drawStats() {
    const m = this.mission;
    const plan = m.plan;
    const item = (id, name, value, hint) => el("span", { class: "stat-item", title: hint || "" },
      el("span", { class: "k", text: name }), el("b", { id, text: value }));
    const parts = [];
    if (m.label) parts.push(el("span", { class: "mission-label", text: `“${m.label}”` }));
    if (plan) {
      parts.push(item("mission-version", "plan", `v${plan.version}`, "the plan's version: a re-plan makes the next"),
        item("mission-makespan", "makespan", fmtDuration(plan.makespan), "when the last robot is home, from the start (robot time)"),
        item("mission-bound", "lower bound", fmtDuration(plan.lower_bound), "no plan can be shorter than this"),
        item("mission-gap", "gap", plan.optimal ? "optimal" : percent(plan.gap), "(makespan − lower bound) / makespan: at most this much longer than the best plan"));
    }
    parts.push(item("mission-progress", "progress", percent(m.progress), "the work done, over every fire"));
    $("mission-stats").replaceChildren(...parts);
  }

  drawTasks() {
    const m = this.mission;
    const plan = m.plan || { tasks: [] };
    const byId = new Map(plan.tasks.map((t) => [t.id, t]));
    const wanted = (m.mission && m.mission.tasks) || [];
    const rows = wanted.map((task) => {
      // A fire the plan has not (yet): pending while planning, else what became of the mission.
      const unplanned = m.state === "planning" ? "pending" : m.state === "canceled" ? "canceled" : "not planned";
      const planned = byId.get(task.id) || { state: unplanned, progress: 0, robots: [] };
      const dot = el("span", { class: "task-dot", "aria-hidden": "true", text: String(wanted.indexOf(task) + 1) });
      dot.style.background = this.overlay.colourOf(task.id);
      const value = planned.state === "done" ? 1 : Math.max(0, Math.min(1, planned.progress || 0));
      const fill = el("span", { class: "fill" });
      fill.style.width = `${(value * 100).toFixed(1)}%`;
      const after = ((m.mission && m.mission.precedence) || []).filter(([, b]) => b === task.id).map(([a]) => a);
      return el("li", { "data-task": task.id, "data-state": planned.state, title: `${task.id}: ${needsOf(task)}${after.length ? ` · after ${after.join(", ")}` : ""}` },
        dot, el("span", { class: "task-id", text: task.id }),
        el("span", { class: "task-state", text: planned.state === "work" ? `work ${percent(value)}` : planned.state }),
        el("span", { class: "task-bar", role: "progressbar", "aria-label": `${task.id} ${planned.state}`, "aria-valuemin": 0, "aria-valuemax": 100, "aria-valuenow": Math.round(value * 100) }, fill),
        el("span", { class: "task-robots", text: `${(planned.robots || []).length} robot${(planned.robots || []).length === 1 ? "" : "s"}` }));
    });
    if (m.reason) rows.unshift(el("li", { class: "reason", id: "mission-reason", text: sentence(m.reason) }));
    $("mission-tasks").replaceChildren(...rows);
  }

  drawHistory() {
    const history = this.mission.history || [];
    $("mission-history").replaceChildren(...history.slice(-4).map((h) => el("li", { "data-state": h.state || "" },
      el("time", { text: fmtClock(h.at) }), el("span", { class: "badge", "data-state": h.state, text: h.state }),
      el("span", { class: "note", text: h.note || "" }))));
  }

  drawChart() {
    const m = this.mission;
    const box = $("gantt");
    if (!m.plan || !(m.plan.robots || []).length) {
      box.replaceChildren(el("p", { class: "muted", id: "gantt-empty",
        text: m.state === "planning" ? "Planning…" : m.state === "rejected" ? "No plan: see the reason." : "No plan to show." }));
      return;
    }
    box.replaceChildren(drawGantt(m, {
      colourOf: (id) => this.overlay.colourOf(id), robotColour: (id) => this.overlay.robotColour(id), now: this.planNow(),
      width: box.clientWidth || undefined,
    }));
  }

  tick() {
    if (this.mission && !MISSION_FINAL.has(this.mission.state) && this.mission.plan) this.drawChart();
  }

  askCancel() {
    const m = this.mission;
    if (!m) return;
    $("mission-cancel-title").textContent = `Cancel ${m.label ? `“${m.label}”` : m.id}?`;
    const robots = ((m.plan && m.plan.robots) || []).length;
    $("mission-cancel-text").textContent = `${m.id} is ${m.state}. Cancelling stops every robot of the mission `
      + `(${robots} robot${robots === 1 ? "" : "s"}) and releases them; the fires not yet done stay undone. It cannot be undone.`;
    $("mission-cancel-dialog").dataset.mission = m.id;
    $("mission-cancel-dialog").showModal();
  }

  async cancel() {
    const dialog = $("mission-cancel-dialog");
    const id = dialog.dataset.mission;
    if (dialog.returnValue !== "cancel" || !id) return;
    dialog.returnValue = "";
    $("mission-cancel").disabled = true;
    const answer = await this.api.cancelMission(id);
    if (!answer.ok) {
      $("mission-error").textContent = sentence(answer.detail);
      $("mission-cancel").disabled = Boolean(this.mission && MISSION_FINAL.has(this.mission.state));
      return;
    }
    if (id === this.id) {
      this.show(answer.data, false);
      if (MISSION_FINAL.has(answer.data.state)) this.stop();
    }
  }
}
