// The Wildfire Suppression Application: wires the map, the form, the REQUESTS
// list and the REQUEST STATE panel to the wildfire server, refreshed every second.

import { api } from "./api.js";
import { drawFront } from "./front.js";
import { RequestForm } from "./form.js";
import { ForestMap } from "./map.js";
import {
  FINAL_STATES, assignCloudColours, cloudColour, el, fmtClock, fmtDuration, fmtNumber, fmtPoint,
  fmtShortDuration,
} from "./util.js";

const REFRESH_MS = 1000;
const CAPABILITIES_EVERY = 3;      // ticks
const STATUSES = ["idle", "reserved", "busy", "charging", "offline"];
const PRIORITY = { balanced: "balanced", time: "time critical", cost: "cost critical" };

const $ = (id) => document.getElementById(id);

const state = {
  selectedId: null,
  selected: null,          // the selected request, as the IaaS last gave it
  selectedKey: "",         // its JSON, to redraw only on change
  items: new Map(),        // request id -> list entry {li, button, ...}
  autoSelected: false,
  tick: 0,
  clouds: "",
};

// --- announcements for screen readers (the panels refresh too often to be live) ---
const announcer = el("p", { class: "sr-only", "aria-live": "polite", id: "announcer" });
document.body.append(announcer);
function announce(text) {
  announcer.textContent = text;
}

// --- the map and the form --------------------------------------------------
const map = new ForestMap($("map"), {
  onPlace: (point) => form.setLocation(point),
});
const form = new RequestForm($("request-form"), {
  onSubmit: send,
  onLocation: (point) => map.setFire(point),
});

async function send(task) {
  const answer = await api.send(task, newKey());
  if (!answer.ok) {
    if (answer.status === 422) {
      form.showServerError(answer.detail);
      form.setResult("The IaaS did not accept the request: see the field marked in red.", "error");
    } else {
      form.showErrors({ form: sentence(answer.detail) });
      form.setResult("The request was not sent.", "error");
    }
    return;
  }
  const request = answer.data;
  form.setResult(`Sent ${request.id}: ${request.state}.`, "ok");
  announce(`Request ${request.id} sent.`);
  await refreshList();
  await select(request.id);
}

function newKey() {
  const bytes = new Uint8Array(16);
  crypto.getRandomValues(bytes);
  return [...bytes].map((b) => b.toString(16).padStart(2, "0")).join("");
}

function sentence(text) {
  const t = String(text || "").trim();
  const s = t.charAt(0).toUpperCase() + t.slice(1);
  return /[.!?]$/.test(s) ? s : `${s}.`;
}

// --- the fleet ---------------------------------------------------------------
async function refreshRobots() {
  const answer = await api.robots();
  const connection = $("connection");
  if (!answer.ok || !Array.isArray(answer.data)) {
    if (connection.dataset.state !== "down") announce(`The IaaS cannot be reached: ${answer.detail}`);
    connection.dataset.state = "down";
    $("connection-text").textContent = sentence(answer.detail || "no robots");
    return;
  }
  const robots = answer.data;
  connection.dataset.state = "ok";
  $("connection-text").textContent = `live · ${fmtNumber(robots.length)} robots`;
  assignCloudColours(new Set(robots.map((r) => r.cloud)));
  map.update(robots);
  drawClouds(robots);
  const counts = Object.fromEntries(STATUSES.map((s) => [s, 0]));
  for (const robot of robots) counts[STATUSES.includes(robot.status) ? robot.status : "offline"] += 1;
  for (const s of STATUSES) $(`count-${s}`).textContent = fmtNumber(counts[s]);
  const clouds = new Set(robots.map((r) => r.cloud)).size;
  $("forest-summary").textContent = `${fmtNumber(robots.length)} robots of ${clouds} cloud${clouds === 1 ? "" : "s"} · metres, grid ${map.gridStep()} m`;
}

function drawClouds(robots) {
  const byCloud = new Map();
  for (const robot of robots) byCloud.set(robot.cloud, (byCloud.get(robot.cloud) || 0) + 1);
  const key = JSON.stringify([...byCloud].sort());
  if (key === state.clouds) return;
  state.clouds = key;
  $("cloud-legend").replaceChildren(...[...byCloud].sort().map(([cloud, count]) => {
    const swatch = el("span", { class: "swatch", "aria-hidden": "true" });
    swatch.style.background = cloudColour(cloud);
    return el("li", { "data-cloud": cloud }, swatch, el("span", { text: cloud }), el("b", { text: fmtNumber(count) }));
  }));
}

async function refreshCapabilities() {
  const answer = await api.capabilities();
  if (answer.ok && Array.isArray(answer.data)) form.setCapabilities(answer.data);
}

async function refreshHealth() {
  const answer = await api.health();
  $("iaas-name").textContent = answer.ok && answer.data?.iaas?.cloud
    ? `IaaS ${answer.data.iaas.cloud}` : "IaaS not reachable";
}

// --- REQUESTS ----------------------------------------------------------------
function taskSummary(task) {
  const needs = Object.entries({ ...(task.actuating || {}), ...(task.sensing || {}) })
    .map(([name, count]) => `${name}×${count}`);
  return `${fmtPoint(task.location)} · ${needs.join(", ")}`;
}

async function refreshList() {
  const answer = await api.requests(50);
  if (!answer.ok || !answer.data) return;
  const items = [...answer.data.items].sort((a, b) => b.created_at.localeCompare(a.created_at));
  const list = $("request-list");
  const seen = new Set();
  let previous = null;
  for (const request of items) {
    seen.add(request.id);
    let entry = state.items.get(request.id);
    if (!entry) {
      entry = listEntry(request);
      state.items.set(request.id, entry);
    }
    updateEntry(entry, request);
    // Keep the order newest first without moving focus.
    const expected = previous ? previous.li.nextSibling : list.firstChild;
    if (expected !== entry.li) {
      if (previous) previous.li.after(entry.li); else list.prepend(entry.li);
    }
    previous = entry;
  }
  for (const [id, entry] of state.items) {
    if (!seen.has(id)) { entry.li.remove(); state.items.delete(id); }
  }
  $("requests-empty").hidden = items.length > 0;
  $("requests-count").textContent = items.length ? `${items.length} shown, newest first` : "";
  if (!state.autoSelected && items.length && !state.selectedId) {
    state.autoSelected = true;
    await select(items[0].id);
  }
}

function listEntry(request) {
  const badge = el("span", { class: "badge" });
  const title = el("span", { class: "title" });
  const meta = el("span", { class: "meta" });
  const when = el("time", { class: "when" });
  const button = el("button", { type: "button", "data-request": request.id },
    badge, el("span", { class: "what" }, title, meta), when);
  button.addEventListener("click", () => select(request.id));
  const li = el("li", { "data-request": request.id }, button);
  return { li, button, badge, title, meta, when };
}

function updateEntry(entry, request) {
  entry.badge.textContent = request.state;
  entry.badge.dataset.state = request.state;
  entry.li.dataset.state = request.state;
  entry.title.textContent = request.label || request.id;
  entry.meta.textContent = `${request.label ? `${request.id} · ` : ""}${taskSummary(request.task)}`;
  entry.when.textContent = fmtClock(request.created_at);
  entry.when.setAttribute("datetime", request.created_at);
  entry.button.setAttribute("aria-label", `${request.label || request.id}, ${request.state}, sent ${fmtClock(request.created_at)}`);
  entry.button.setAttribute("aria-current", String(request.id === state.selectedId));
}

// --- REQUEST STATE -----------------------------------------------------------
async function select(id) {
  state.selectedId = id;
  state.selectedKey = "";
  $("lookup-id").value = id;
  $("err-lookup").textContent = "";
  $("lookup-id").removeAttribute("aria-invalid");
  $("cancel-result").textContent = "";
  for (const entry of state.items.values()) {
    entry.button.setAttribute("aria-current", String(entry.button.dataset.request === id));
  }
  await refreshSelected();
}

async function refreshSelected() {
  const id = state.selectedId;
  if (!id) return;
  const answer = await api.request(id);
  if (id !== state.selectedId) return;
  if (!answer.ok) {
    $("err-lookup").textContent = sentence(answer.detail);
    return;
  }
  showRequest(answer.data);
}

function showRequest(request) {
  const key = JSON.stringify(request);
  if (key === state.selectedKey) return;
  const before = state.selected;
  if (before && before.id === request.id && before.state !== request.state) {
    announce(`Request ${request.id} is ${request.state}.`);
  }
  state.selected = request;
  state.selectedKey = key;
  const cancel = $("cancel");
  cancel.disabled = FINAL_STATES.has(request.state);
  map.select(request);
  $("state-body").replaceChildren(...stateView(request));
  const entry = state.items.get(request.id);
  if (entry) updateEntry(entry, request);
}

function stateView(request) {
  const parts = [];
  parts.push(el("div", { class: "state-head", id: "state-head", "data-request": request.id, "data-state": request.state },
    el("span", { class: "badge", "data-state": request.state, id: "state-badge", text: request.state }),
    el("span", { class: "rid", text: request.id }),
    request.label ? el("span", { class: "label", text: request.label }) : null));
  const task = request.task || {};
  parts.push(el("p", { class: "muted task-line",
    text: `Fire at ${fmtPoint(task.location)} · ${taskSummary(task).split(" · ")[1] || ""} · at most `
      + `${fmtNumber(task.max_robots)} robots, ${fmtNumber(task.max_cost)} cost, ${fmtDuration(task.max_time)}`
      + ` · battery ≥ ${fmtNumber(task.min_battery)}% · ${PRIORITY[task.priority] || task.priority} · ${task.execution}` }));
  if (request.reason) parts.push(el("p", { class: "reason", id: "state-reason", text: sentence(request.reason) }));

  const coalition = request.coalition || [];
  parts.push(el("div", { class: "stats" },
    stat("Time", request.time === null ? "–" : fmtShortDuration(request.time)),
    stat("Cost", request.cost === null ? "–" : fmtNumber(request.cost, 2)),
    stat("Robots", coalition.length ? fmtNumber(coalition.length) : "–"),
    stat("Selection", request.optimizer ? `${request.optimizer}${request.selection_ms !== null ? ` · ${fmtNumber(request.selection_ms, 1)} ms` : ""}` : "–")));

  const front = request.pareto || [];
  const frontBox = el("div", { class: "front", id: "front" },
    el("h3", { class: "subhead" }, el("span", { text: "Pareto front" }),
      el("span", { class: "hint", text: front.length ? `${front.length} coalition${front.length === 1 ? "" : "s"} · marker size = robots` : "" })));
  if (front.length) frontBox.append(drawFront(request));
  else frontBox.append(el("p", { class: "muted", text: emptyFront(request.state) }));
  parts.push(frontBox);

  if (coalition.length) {
    const rows = coalition.map((a) => {
      const swatch = el("span", { class: "swatch", "aria-hidden": "true" });
      swatch.style.background = cloudColour(a.cloud);
      const phase = a.progress?.phase || "pending";
      const value = Math.max(0, Math.min(1, a.progress?.progress ?? 0));
      const fill = el("div", { class: "fill" });
      fill.style.width = `${(value * 100).toFixed(1)}%`;
      return el("tr", { "data-robot": a.robot },
        el("td", {}, el("span", { class: "robot-id" }, swatch, a.robot), el("span", { class: "cloud", text: a.cloud })),
        el("td", { text: a.capabilities.join(", ") }),
        el("td", { class: "num", text: fmtShortDuration(a.time) }),
        el("td", { class: "num", text: fmtNumber(a.cost, 2) }),
        el("td", {}, el("div", { class: "progress", "data-phase": phase, role: "progressbar",
          "aria-valuemin": 0, "aria-valuemax": 100, "aria-valuenow": Math.round(value * 100), "aria-label": `${a.robot} ${phase}` },
        el("div", { class: "track" }, fill), el("span", { class: "phase", text: phase }))));
    });
    parts.push(el("div", { class: "coalition-box" },
      el("h3", { class: "subhead" }, el("span", { text: "Coalition" }), el("span", { class: "hint", text: "highlighted on the map" })),
      el("div", { class: "table-scroll" }, el("table", { class: "coalition", id: "coalition" },
        el("thead", {}, el("tr", {}, el("th", { text: "Robot" }), el("th", { text: "Capabilities" }),
          el("th", { class: "num", text: "Time" }), el("th", { class: "num", text: "Cost" }), el("th", { text: "Progress" }))),
        el("tbody", {}, ...rows)))));
  }

  parts.push(el("div", { class: "history-box" },
    el("h3", { class: "subhead", text: "History" }),
    el("ol", { class: "history", id: "history" }, ...(request.history || []).map((h) => el("li", { "data-state": h.state, "data-kind": h.kind },
      el("time", { datetime: h.at, text: fmtClock(h.at) }),
      h.kind === "state" ? el("span", { class: "badge", "data-state": h.state, text: h.state }) : el("span", { class: "event", text: "event" }),
      el("span", { class: "detail", text: h.detail || "" }))))));
  return parts;
}

function stat(name, value) {
  return el("div", { class: "stat" }, el("div", { class: "k", text: name }), el("div", { class: "v", text: value }));
}

function emptyFront(requestState) {
  if (requestState === "received" || requestState === "selecting") return "Selecting a coalition…";
  if (requestState === "rejected") return "No feasible coalition: nothing to plot.";
  return "No front was computed for this request.";
}

// --- the thesis's other two buttons --------------------------------------------
$("lookup-form").addEventListener("submit", async (event) => {
  event.preventDefault();
  const input = $("lookup-id");
  const id = input.value.trim();
  if (!id) {
    $("err-lookup").textContent = "Type a request id, or pick one from the list.";
    input.setAttribute("aria-invalid", "true");
    input.focus();
    return;
  }
  const answer = await api.request(id);
  if (!answer.ok) {
    $("err-lookup").textContent = sentence(answer.detail);
    input.setAttribute("aria-invalid", "true");
    return;
  }
  await select(id);
});

$("cancel").addEventListener("click", async () => {
  const id = state.selectedId;
  if (!id) return;
  const result = $("cancel-result");
  const button = $("cancel");
  button.disabled = true;
  const answer = await api.cancel(id);
  if (answer.ok) {
    result.textContent = `${id} is ${answer.data.state}.`;
    result.dataset.kind = "ok";
    state.selectedKey = "";
    showRequest(answer.data);
    await refreshList();
  } else {
    result.textContent = sentence(answer.detail);
    result.dataset.kind = "error";
    button.disabled = Boolean(state.selected && FINAL_STATES.has(state.selected.state));
  }
  announce(result.textContent);
});

// --- the refresh loop ----------------------------------------------------------
async function tick() {
  try {
    const capabilities = state.tick % CAPABILITIES_EVERY === 0 ? refreshCapabilities() : null;
    await Promise.all([refreshRobots(), refreshList(), capabilities]);
    await refreshSelected();
  } finally {
    state.tick += 1;
    setTimeout(tick, REFRESH_MS);
  }
}

refreshHealth();
tick();
