// The Wildfire Suppression Application: wires the live feed, the map, the
// form, the tables, the REQUEST STATE panel and the missions together.
//
// Why one long file: it is the page's composition root, where each part
// (its own module) meets the others through callbacks; the parts' own work
// (drawing, checking, sending, following) stays in their modules.

import { api } from "./api.js";
import { Banner } from "./banner.js";
import { RequestForm } from "./form.js";
import { Live } from "./live.js";
import { ForestMap } from "./map.js";
import { MissionBuilder } from "./mission.js";
import { MissionView } from "./missionview.js";
import { MissionOverlay } from "./routes.js";
import { Sender } from "./sender.js";
import { requestName, StatePanel } from "./state.js";
import { REQUESTS_PER_PAGE, RequestsTable, RobotsTable } from "./tables.js";
import {
  $, el, FINAL_STATES, fmtAge, fmtClock, fmtDuration, fmtNumber, humanize, REQUEST_STATES, sentence, setStates,
  setCloudColours, STATUSES,
} from "./util.js";

const page = {
  selectedId: null,
  selected: null,          // the selected request, as its IaaS last gave it
  selectedRev: null,
  requestsQuery: { state: "", cursors: [""], index: 0, next: null },
  reloadTimer: null,
  requestsTicket: 0,       // the latest load of the requests table (older answers are dropped)
  unread: 0,
  bannerKey: null,
  cardRobot: null,
  tab: "send",
  tableTab: "requests",
  snapshots: 0,
};

// --- announcements for screen readers (the panels change too often to be live) ---
const announcer = el("p", { class: "sr-only", "aria-live": "polite", id: "announcer" });
document.body.append(announcer);
function announce(text) {
  announcer.textContent = text;
}

// --- the parts -----------------------------------------------------------------
const live = new Live({ onSnapshot, onDelta, onLink });
const banner = new Banner(live);
const map = new ForestMap($("map"), {
  onPlace: (point) => form.setLocation(point),
  onRobot: (id) => showRobotCard(id),
  onEnd: (point) => missions.setEnd(point),
});
map.ageOf = (robot) => live.age(robot);
const form = new RequestForm($("request-form"), {
  onSubmit: (task) => sender.submit(task),
  onCheck: () => sender.forget(),
  onLocation: (point) => map.setFire(point),
  onMission: () => missions.submit(),
});
const sender = new Sender({ api, onChange: showSend });
// Several fires as one mission: built in the form, followed under MISSION, drawn on the map.
const overlay = new MissionOverlay(map);
const missions = new MissionBuilder({
  api, form,
  onChange: (builder) => overlay.setDraft(builder.fires, builder.end()),
  onSent: (mission) => missionView.follow(mission.id),
  onAdded: () => map.setFire(null),
});
const missionView = new MissionView({
  api, live, overlay,
  onShow: () => { showTableTab("mission"); if (page.tab !== "send") showTab("mission"); },
  onState: (mission) => announce(`Mission ${mission.id} is ${mission.state}.`),
  onMission: (mission) => missions.say(mission),
});
for (const radio of document.querySelectorAll("input[name=send-mode]")) {
  radio.addEventListener("change", () => {
    if (!radio.checked) return;
    form.setMode(radio.value);
    if (radio.value !== "mission" && $("mode-end").checked) { $("mode-fire").checked = true; map.setMode("fire"); }
  });
}
const statePanel = new StatePanel($("state-body"), { live });
const robotsTable = new RobotsTable($("robots-table"), {
  live,
  onRow: (id) => showRobotCard(id),
  summary: $("robots-count"),
  pager: { previous: $("robots-previous"), next: $("robots-next"), label: $("robots-page") },
});
robotsTable.visible = false;
const requestsTable = new RequestsTable($("requests-table"), { live, onRow: (id) => select(id) });

// --- the live feed -----------------------------------------------------------------
function onSnapshot() {
  // A snapshot after the first is a reconnection: what was missed is read again.
  if (page.snapshots++) {
    reloadRequests(0);
    refreshSelected();
  }
  setCloudColours(live.clouds);
  applyConfig();
  const seen = new Set();
  for (const robot of live.robots.values()) {
    map.upsert(robot);
    seen.add(robot.id);
  }
  for (const id of [...map.robots.keys()]) if (!seen.has(id)) map.remove(id);
  map.drawSelection();
  form.setCapabilities(live.capabilities);
  fillCapabilityFilter();
  drawHeader();
  drawCounts();
  drawAlerts();
  banner.take(live.alerts);
  drawBanner();
  robotsTable.render();
  for (const summary of live.requests.values()) requestsTable.update(summary);
  requestsTable.render();
}

function onDelta(_, change) {
  if (change.data.clouds) setCloudColours(live.clouds);
  if (change.data.config) applyConfig();
  for (const id of change.added) map.upsert(live.robots.get(id));
  for (const id of change.changed) map.upsert(live.robots.get(id));
  for (const id of change.removed) map.remove(id);
  if (page.selected && page.selected.coalition) map.drawSelection();
  if (change.data.capabilities) {
    form.setCapabilities(live.capabilities);
    fillCapabilityFilter();
  }
  drawHeader();
  drawCounts();
  if (change.alerts.length) newAlerts(change.alerts);
  else drawBanner();
  robotsTable.render();
  followRequests(change.requests);
  if (page.cardRobot) showRobotCard(page.cardRobot, false);
}

function onLink(link) {
  document.body.dataset.link = link;
  if (link === "live") {
    if (page.lostAt) {
      newAlerts([{ id: `link-${Date.now()}`, at: live.now(), level: "ok", kind: "server",
        text: "The wildfire server answers again: the page is live." }], true);
      page.lostAt = null;
    }
  } else if (link !== "connecting" && !page.lostAt) {
    page.lostAt = live.localNow();
    newAlerts([{ id: `link-${Date.now()}`, at: live.now(), level: "danger", kind: "server",
      text: link === "down" ? "The wildfire server cannot be reached: the page shows the fleet and the requests as last heard, greyed."
        : `The wildfire server has sent nothing for ${fmtNumber(live.silentAfter())} s: the page shows what it last heard, greyed.` }], true);
  }
  drawHeader();
  drawBanner();
}

function applyConfig() {
  const config = live.config;
  if (!config) return;
  map.setForest(config.forest);
  form.setForest(config.forest);
  form.setUnits(config.currency, live.timeScale());
  form.setLimits(config.limits);
  if (!REQUEST_STATES.length) {
    setStates(config.states);
    for (const s of REQUEST_STATES) $("requests-state").append(el("option", { value: s, text: s }));
  }
  const f = config.forest;
  $("forest-hint").textContent = `The forest: x ${fmtNumber(f.x0)}–${fmtNumber(f.x1)}, y ${fmtNumber(f.y0)}–${fmtNumber(f.y1)} m.`;
  const clock = $("clock-scale");
  const scale = live.timeScale();
  clock.hidden = scale === 1;
  clock.textContent = `Robot clock ×${fmtNumber(scale, Number.isInteger(scale) ? 0 : 1)}`;
  clock.title = `The robots run ${fmtNumber(scale, 1)} times faster than real time: times of robots and tasks `
    + "(max time, a coalition's time) are on the robot clock; elapsed times and ETAs are real time.";
}

// --- the header: clouds, clock, link ---------------------------------------------------
function drawHeader() {
  const now = live.now();
  const primary = live.endpoints.find((e) => e.ok);
  $("iaas-name").textContent = primary ? `requests go to ${primary.cloud || primary.url}` : "no IaaS answers";
  const chips = live.clouds.map((cloud) => {
    const swatch = el("span", { class: "swatch", "aria-hidden": "true" });
    swatch.style.background = cloud.colour;
    const state = cloud.status === "up" ? `${fmtNumber(cloud.robots)}`
      : cloud.status === "down" ? `down ${fmtDuration(now - cloud.since)}` : "not seen";
    const title = cloud.status === "up"
      ? `${cloud.name}: live, ${cloud.robots} robots (${cloud.idle} idle, ${cloud.offline} offline)${cloud.iaas ? `; IaaS ${cloud.iaas}` : ""}`
      : `${cloud.name}: ${cloud.status} since ${fmtClock(cloud.since)}: ${cloud.reason || ""}`;
    return el("li", { "data-cloud": cloud.name, "data-status": cloud.status, title },
      swatch, el("span", { class: "name", text: cloud.name }), el("b", { text: state }));
  });
  const key = chips.map((c) => c.title + c.textContent).join("|");
  if (key !== page.chipsKey) {
    page.chipsKey = key;
    $("cloud-health").replaceChildren(...chips);
  }
  const connection = $("connection");
  const text = $("connection-text");
  if (live.link === "live") {
    const down = live.clouds.filter((c) => c.status !== "up").length;
    connection.dataset.state = !primary ? "down" : down ? "partial" : "ok";
    text.textContent = !primary ? "no IaaS answers" : down ? `live · ${down} cloud${down === 1 ? "" : "s"} down` : `live · ${fmtNumber(live.robots.size)} robots`;
  } else if (live.link === "connecting") {
    connection.dataset.state = "wait";
    text.textContent = "connecting…";
  } else {
    connection.dataset.state = "down";
    text.textContent = `server lost ${fmtDuration(live.localNow() - live.linkSince)} ago`;
  }
}

function drawCounts() {
  const counts = Object.fromEntries(STATUSES.map((s) => [s, 0]));
  let stale = 0;
  let shown = 0;
  for (const robot of live.robots.values()) {
    counts[STATUSES.includes(robot.status) ? robot.status : "offline"] += 1;
    if (robot.heard !== null && robot.heard !== undefined) stale += 1;
    if (map.matches(robot)) shown += 1;
  }
  for (const s of STATUSES) $(`count-${s}`).textContent = fmtNumber(counts[s]);
  $("count-stale").textContent = fmtNumber(stale);
  const clouds = live.clouds.length;
  const total = live.robots.size;
  $("forest-summary").textContent = `${fmtNumber(total)} robots of ${clouds} cloud${clouds === 1 ? "" : "s"}`
    + (shown < total ? ` · ${fmtNumber(shown)} shown` : "") + ` · ${map.visibleArea()}`;
}

// --- alerts -----------------------------------------------------------------------
function alertItem(alert) {
  return el("li", { "data-level": alert.level, "data-kind": alert.kind, "data-alert": alert.id },
    el("time", { text: fmtClock(alert.at) }), el("span", { text: alert.text }));
}

function drawAlerts() {
  const list = $("alert-list");
  list.replaceChildren(...[...live.alerts].reverse().map(alertItem));
  $("alerts-empty").hidden = live.alerts.length > 0;
}

function newAlerts(alerts, local = false) {
  if (local) live.alerts.push(...alerts);
  drawAlerts();
  if ($("alerts-panel").hidden) page.unread += alerts.length;
  $("alerts-count").textContent = String(page.unread);
  $("alerts-button").dataset.unread = String(page.unread > 0);
  banner.take(alerts);
  const before = page.bannerKey;
  const shown = drawBanner();
  if (shown && shown.key !== before) announce(shown.text);
}

function drawBanner() {
  const shown = banner.draw($("banner"), $("banner-text"));
  page.bannerKey = shown ? shown.key : null;
  return shown;
}

$("banner-close").addEventListener("click", () => {
  banner.dismiss($("banner").dataset.key);
  drawBanner();
});
$("alerts-button").addEventListener("click", () => {
  const panel = $("alerts-panel");
  panel.hidden = !panel.hidden;
  $("alerts-button").setAttribute("aria-expanded", String(!panel.hidden));
  if (!panel.hidden) {
    page.unread = 0;
    $("alerts-count").textContent = "0";
    $("alerts-button").dataset.unread = "false";
  }
});

// --- sending ---------------------------------------------------------------------------
function showSend(submission) {
  if (form.showPending(submission, "request")) return;
  const detail = sentence(humanize(submission.detail || ""));
  switch (submission.state) {
    case "confirmed": {
      form.setBusy(false);
      const request = submission.request;
      // The IaaS has it, and has not chosen yet: neither green nor red until
      // its own answer says what became of it (followSent).
      sayWhereSent(request);
      announce(`Request ${request.id} sent.`);
      live.requests.set(request.id, { ...(live.requests.get(request.id) || {}), id: request.id, state: request.state });
      reloadRequests(0);
      select(request.id);
      showTab("state");
      break;
    }
    case "refused":
      form.setBusy(false);
      if (submission.status === 422) {
        form.showServerError(submission.detail);
        form.setResult("The request was refused: see the field marked in red. Nothing was sent to the robots.", "error");
      } else {
        form.showErrors({ form: detail });
        form.setResult("The request was refused. Nothing was sent to the robots.", "error");
      }
      break;
    case "stopped":
      form.setBusy(false);
      form.setResult(submission.maybeDelivered
        ? "Stopped checking. The request may have reached the IaaS: if it did, it will show in Requests."
        : "Stopped. No IaaS received the request, so nothing was sent; you can send it again.", "pending");
      break;
    default:
      break;
  }
}
$("stop-checking").addEventListener("click", () => { sender.stop(); missions.stop(); });

// The send's line follows its request, in the IaaS's words: green only once
// the IaaS says robots are on their way, so a rejection is never green.
function sayWhereSent(summary) {
  const name = summary.label ? `${summary.id} (“${summary.label}”)` : summary.id;
  const robots = (summary.robots || summary.coalition || []).length;
  switch (summary.state) {
    case "rejected":
    case "failed":
      form.setResult(`${name} was ${summary.state}: ${sentence(humanize(summary.reason || "no reason given"))}`, "error");
      break;
    case "canceled":
      form.setResult(`${name} was canceled.`, "info");
      break;
    case "dispatched":
    case "underway":
      form.setResult(`Sent ${name}: ${summary.state}${robots ? `, ${robots} robot${robots === 1 ? "" : "s"}` : ""}.`, "ok");
      break;
    case "completed":
      form.setResult(`Sent ${name}: completed.`, "ok");
      break;
    default:
      form.setResult(`Sent ${name}: the IaaS has it (${summary.state}) and is choosing a coalition…`, "info");
  }
}

function followSent(summary) {
  const submission = sender.current;
  if (!submission || submission.state !== "confirmed" || submission.request.id !== summary.id) return;
  sayWhereSent(summary);
}

// --- requests ---------------------------------------------------------------------------
function followRequests(summaries) {
  let fresh = false;
  for (const summary of summaries) {
    if (!requestsTable.update(summary)) fresh = true;
    followSent(summary);
    if (summary.id === page.selectedId && summary.rev !== page.selectedRev) refreshSelected();
  }
  const q = page.requestsQuery;
  if (fresh && q.index === 0) reloadRequests(300);
  else if (summaries.length) requestsTable.render();
}

function reloadRequests(delay = 0) {
  clearTimeout(page.reloadTimer);
  page.reloadTimer = setTimeout(loadRequests, delay);
}

async function loadRequests() {
  clearTimeout(page.reloadTimer);
  const q = page.requestsQuery;
  // Only the answer to the latest load is shown: a reload of page 1 answered after a
  // click on "older" would otherwise fill page 2 with page 1's rows.
  const ticket = ++page.requestsTicket;
  const answer = await api.requests({ state: q.state, limit: REQUESTS_PER_PAGE, before: q.cursors[q.index] });
  if (ticket !== page.requestsTicket) return;
  if (!answer.ok) {
    $("requests-error").textContent = sentence(answer.detail);
    return;
  }
  $("requests-error").textContent = (answer.data.missing || []).map(sentence).join(" ");
  const items = answer.data.items.map((item) => ({ ...item, ...(live.requests.get(item.id)?.rev === item.rev ? live.requests.get(item.id) : {}) }));
  requestsTable.setItems(items);
  q.next = answer.data.next;
  $("requests-newer").disabled = q.index === 0;
  $("requests-older").disabled = !q.next;
  $("requests-page").textContent = `page ${q.index + 1}`;
  const from = q.index * REQUESTS_PER_PAGE;
  $("requests-count").textContent = items.length
    ? `${fmtNumber(from + 1)}–${fmtNumber(from + items.length)}${q.state ? ` ${q.state}` : ""}, newest first` : "";
  $("requests-empty").hidden = items.length > 0 || q.index > 0;
  $("requests-empty").textContent = q.state ? `No ${q.state} requests.` : "No requests yet: place the fire and send one.";
  // The newest request is shown once, unless the operator is already in the id field
  // (its text would be replaced under the cursor, or the id typed onto it).
  if (!page.selectedId && !page.autoSelected && items.length
      && document.activeElement !== $("lookup-id")) {
    page.autoSelected = true;
    select(items[0].id);
  }
}

$("requests-state").addEventListener("change", () => {
  page.requestsQuery = { state: $("requests-state").value, cursors: [""], index: 0, next: null };
  loadRequests();
});
$("requests-older").addEventListener("click", () => {
  const q = page.requestsQuery;
  if (!q.next) return;
  q.cursors[q.index + 1] = q.next;
  q.index += 1;
  loadRequests();
});
$("requests-newer").addEventListener("click", () => {
  const q = page.requestsQuery;
  if (q.index === 0) return;
  q.index -= 1;
  loadRequests();
});

// --- REQUEST STATE ------------------------------------------------------------------------
async function select(id) {
  page.autoSelected = true;
  page.selectedId = id;
  page.selectedRev = null;
  $("lookup-id").value = id;
  $("err-lookup").textContent = "";
  $("lookup-id").removeAttribute("aria-invalid");
  $("cancel-result").textContent = "";
  requestsTable.selectedId = id;
  requestsTable.render();
  await refreshSelected();
}

async function refreshSelected() {
  const id = page.selectedId;
  if (!id) return;
  const answer = await api.request(id);
  if (id !== page.selectedId) return;
  if (!answer.ok) {
    $("err-lookup").textContent = sentence(answer.detail);
    return;
  }
  showRequest(answer.data);
}

function showRequest(request) {
  const before = page.selected;
  if (before && before.id === request.id && before.state !== request.state) {
    announce(`Request ${request.id} is ${request.state}.`);
  }
  page.selected = request;
  page.selectedRev = `${request.updated_at}/${(request.history || []).length}`;
  const summary = live.requests.get(request.id);
  if (summary && summary.rev !== page.selectedRev && summary.updated_at < request.updated_at) live.requests.set(request.id, { ...summary, state: request.state });
  $("cancel").disabled = FINAL_STATES.has(request.state);
  followSent(request);
  map.select(request);
  statePanel.show(request);
}

// An operator typing an id has chosen: a first list arriving late must not select over it.
$("lookup-id").addEventListener("input", () => { page.autoSelected = true; });

$("lookup-form").addEventListener("submit", async (event) => {
  event.preventDefault();
  page.autoSelected = true;  // the operator chose: the first list must not select over it
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

// Cancel asks first, naming the request.
$("cancel").addEventListener("click", () => {
  const request = page.selected;
  if (!request) return;
  $("cancel-dialog-title").textContent = `Cancel ${request.label ? `“${request.label}”` : request.id}?`;
  $("cancel-dialog-text").textContent = `${requestName(request)} is ${request.state}. Cancelling stops every robot `
    + "of its coalition and releases them; it cannot be undone.";
  $("cancel-dialog").dataset.request = request.id;
  $("cancel-dialog").showModal();
});

$("cancel-dialog").addEventListener("close", async () => {
  const dialog = $("cancel-dialog");
  const id = dialog.dataset.request;
  if (dialog.returnValue !== "cancel" || !id) {
    $("cancel").focus();
    return;
  }
  dialog.returnValue = "";
  const result = $("cancel-result");
  const button = $("cancel");
  button.disabled = true;
  const answer = await api.cancel(id);
  if (answer.ok) {
    result.textContent = `${id} is ${answer.data.state}.`;
    result.dataset.kind = "ok";
    if (id === page.selectedId) showRequest(answer.data);
    reloadRequests(0);
  } else {
    result.textContent = sentence(answer.detail);
    result.dataset.kind = "error";
    button.disabled = Boolean(page.selected && FINAL_STATES.has(page.selected.state));
  }
  announce(result.textContent);
});

// --- the map's tools ------------------------------------------------------------------------
function fillCapabilityFilter() {
  const select = $("filter-capability");
  const names = live.capabilities.map((c) => c.name).sort();
  const have = [...select.options].slice(1).map((o) => o.value);
  if (names.join() === have.join()) return;
  const value = select.value;
  select.replaceChildren(el("option", { value: "", text: "all capabilities" }), ...names.map((n) => el("option", { value: n, text: n })));
  select.value = names.includes(value) ? value : "";
}

function fillCloudFilter() {
  const select = $("filter-cloud");
  const names = live.clouds.map((c) => c.name);
  const have = [...select.options].slice(1).map((o) => o.value);
  if (names.join() === have.join()) return;
  const value = select.value;
  select.replaceChildren(el("option", { value: "", text: "all clouds" }), ...names.map((n) => el("option", { value: n, text: n })));
  select.value = names.includes(value) ? value : "";
}

function applyFilters() {
  const filter = { cloud: $("filter-cloud").value, status: $("filter-status").value, capability: $("filter-capability").value };
  map.setFilter(filter);
  robotsTable.setFilter((robot) => map.matches(robot), $("robots-search").value);
  drawCounts();
}
for (const id of ["filter-cloud", "filter-status", "filter-capability"]) $(id).addEventListener("change", applyFilters);
$("robots-search").addEventListener("input", applyFilters);
$("robots-previous").addEventListener("click", () => robotsTable.turn(-1));
$("robots-next").addEventListener("click", () => robotsTable.turn(1));

function showZoom() {
  $("zoom-level").textContent = `×${fmtNumber(map.view.k, map.view.k < 10 ? 1 : 0)}`;
  drawCounts();
}
new MutationObserver(showZoom).observe($("map"), { attributes: true, attributeFilter: ["data-zoom"] });
for (const radio of document.querySelectorAll("input[name=map-mode]")) {
  radio.addEventListener("change", () => { if (radio.checked) map.setMode(radio.value); });
}
$("zoom-in").addEventListener("click", () => map.zoomBy(1.5));
$("zoom-out").addEventListener("click", () => map.zoomBy(1 / 1.5));
$("zoom-reset").addEventListener("click", () => map.reset());

// A robot's details, on a tap or a click (hover shows them too, as a tooltip).
function showRobotCard(id, move = true) {
  const card = $("robot-card");
  const robot = id && live.robots.get(id);
  if (!robot) {
    card.hidden = true;
    page.cardRobot = null;
    return;
  }
  page.cardRobot = id;
  const assignment = live.assignments().get(id);
  const age = live.age(robot);
  const staleAfter = (live.config && live.config.stale_after) || 5;
  const rows = [
    ["Cloud", robot.cloud], ["Status", robot.status], ["Battery", `${fmtNumber(robot.battery)}%`],
    ["Capabilities", (robot.capabilities || []).join(", ") || "–"],
    ["Request", assignment ? requestName(assignment.request) : missionView.taskName(robot.request)
      || (robot.request ? `${robot.request} (not this application's)` : "–")],
    ["Task", robot.phase ? `${robot.phase}${Number.isFinite(robot.progress) ? ` · ${Math.round(robot.progress * 100)}%` : ""}` : "–"],
    ["ETA", assignment ? fmtDuration(live.robotEta(robot, assignment.time)) : "–"],
    ["Position", `(${fmtNumber(robot.x)}, ${fmtNumber(robot.y)}) m`],
    ["Last heard", age === null ? `within the last ${fmtNumber(staleAfter)} s` : `${fmtAge(age)} (stale: greyed)`],
  ];
  $("robot-card-title").textContent = robot.id;
  $("robot-card-body").replaceChildren(...rows.flatMap(([k, v]) => [el("dt", { text: k }), el("dd", { text: v })]));
  $("robot-card-note").textContent = statusMeaning(robot, assignment, age);
  card.dataset.robot = id;
  card.classList.toggle("stale", age !== null);
  card.hidden = false;
  if (move) {
    const point = map.clientPoint(id);
    const wrap = $("map-wrap").getBoundingClientRect();
    if (point) {
      const left = Math.min(Math.max(4, point.x - wrap.left + 14), wrap.width - card.offsetWidth - 4);
      const top = Math.min(Math.max(4, point.y - wrap.top + 14), wrap.height - card.offsetHeight - 4);
      card.style.left = `${left}px`;
      card.style.top = `${top}px`;
    }
  }
}
$("robot-card-close").addEventListener("click", () => showRobotCard(null));

// What a robot's status means, in a sentence, for its card.
function statusMeaning(robot, assignment, age) {
  const task = missionView.taskName(robot.request);
  const ours = assignment ? `for ${requestName(assignment.request)}, one of this application's requests`
    : task ? `for ${task}, one of this application's missions` : null;
  const theirs = robot.request ? `for request ${robot.request}, not one of this application's`
    : "for work outside this application (another user of its cloud)";
  let text;
  switch (robot.status) {
    case "idle": text = "Idle: free, it may be chosen for a request."; break;
    case "reserved": text = `Reserved ${ours || theirs}: held for a coalition, not free to be chosen.`; break;
    case "busy": text = `Busy ${ours || theirs}: at work, not free to be chosen.`; break;
    case "charging": text = "Charging: not available until its battery is charged."; break;
    default:
      text = "Offline: out of service: it says it is off (a flat battery, switched off), or its IaaS "
        + "has not heard from it for a few seconds (5 by default). It is never chosen while offline.";
  }
  if (age !== null) text += ` Not heard for ${fmtAge(age).replace(" ago", "")}: what it shows may be old.`;
  return text;
}

// --- tabs: the tables' (Requests, Robots) and, on a phone, the page's ----------------------
const TABLE_TABS = ["requests", "robots", "mission"];
function showTableTab(name) {
  page.tableTab = name;
  document.body.dataset.table = name;
  for (const tab of TABLE_TABS) {
    const on = tab === name;
    $(`tab-${tab}`).setAttribute("aria-selected", String(on));
    $(`tab-${tab}`).tabIndex = on ? 0 : -1;
    $(`${tab}-view`).hidden = !on;
  }
  robotsTable.visible = name === "robots";
  robotsTable.render();
  if (name === "mission") missionView.loadList();  // missions sent from elsewhere, too
}
TABLE_TABS.forEach((tab, i) => {
  $(`tab-${tab}`).addEventListener("click", () => showTableTab(tab));
  $(`tab-${tab}`).addEventListener("keydown", (e) => {
    const next = TABLE_TABS[i + (e.key === "ArrowRight" ? 1 : e.key === "ArrowLeft" ? -1 : 0)];
    if (next && next !== tab) { showTableTab(next); $(`tab-${next}`).focus(); }
  });
});

function showTab(name) {
  page.tab = name;
  document.body.dataset.tab = name;
  for (const button of $("tabs").querySelectorAll("button")) {
    if (button.dataset.tab === name) button.setAttribute("aria-current", "page");
    else button.removeAttribute("aria-current");
  }
}
for (const button of $("tabs").querySelectorAll("button")) {
  button.addEventListener("click", () => {
    showTab(button.dataset.tab);
    if (button.dataset.tab === "mission") showTableTab("mission");
    else if (button.dataset.tab === "requests" && page.tableTab === "mission") showTableTab("requests");
  });
}

// --- every second: clocks and ages ----------------------------------------------------------
setInterval(() => {
  fillCloudFilter();
  drawHeader();
  drawBanner();
  statePanel.tick();
  if (page.tableTab === "requests") requestsTable.render();
  if (live.link !== "live") document.body.dataset.staleFor = fmtDuration(live.localNow() - live.linkSince);
}, 1000);

live.start();
loadRequests();
missionView.loadList();
