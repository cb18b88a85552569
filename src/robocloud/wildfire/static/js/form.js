// "Send a Request": the task form. Every field is checked here as docs/model.md
// asks (and the fire must be in the application's forest), and the error is
// shown beside its field; the IaaS's own sentence (422) is placed beside the
// field it names, in the form's words.

import { pendingLine } from "./sender.js";
import { el, fmtDuration, fmtNumber, humanize, sentence } from "./util.js";

const FIELDS = ["location", "capabilities", "max_robots", "max_cost", "max_time", "min_battery", "label", "mission", "form"];

// What each priority does to the final choice among the Pareto-optimal
// coalitions (docs/model.md), one line each.
const PRIORITY_TEXT = {
  balanced: "Balanced: time, cost and size weigh a third each, by how much the coalitions differ.",
  time: "Time critical: favours quicker coalitions: time weighs 0.6, cost and size 0.2 each.",
  cost: "Cost critical: favours cheaper coalitions: cost weighs 0.6, time and size 0.2 each.",
};

// What each priority asks of a mission's plan (docs/model.md, "The objective, by priority").
const MISSION_PRIORITY_TEXT = {
  balanced: "Balanced: the cheapest plan whose last robot is home at most a tenth later than in the quickest plan found.",
  time: "Time critical: the plan whose last robot is home first; the cheapest of those.",
  cost: "Cost critical: the cheapest plan within max time (any time, without one).",
};

// The task's bounds, as the IaaS's own schema gives them (GET /api/config
// "limits", read by the server from the IaaS's /openapi.json). Until they come,
// a bound is not checked here: the IaaS's own sentence says it.
const NO_LIMITS = {
  count: { min: 1, max: null }, max_robots: { min: 1, max: null }, max_cost: { min: 0, max: null },
  max_time: { min: 0, max: null }, min_battery: { min: 0, max: 100 }, label: { max_length: 200 },
};

function metres(value) {
  return fmtNumber(value, Number.isInteger(value) ? 0 : 1);
}

// The server's sentence refusing a fire outside the forest (config.py Forest.refusal).
export function forestRefusal(forest, x, y) {
  if (!forest || (x >= forest.x0 && x <= forest.x1 && y >= forest.y0 && y <= forest.y1)) return null;
  return `The fire at (${metres(x)}, ${metres(y)}) is outside the forest, which spans x from `
    + `${metres(forest.x0)} to ${metres(forest.x1)} m and y from ${metres(forest.y0)} to ${metres(forest.y1)} m.`;
}

const upTo = (max) => (Number.isFinite(max) ? ` to ${fmtNumber(max)}` : " or more");
const within = (value, { min, max }) => value >= min && !(Number.isFinite(max) && value > max);

function readNumber(input) {
  const text = input.value.trim();
  if (text === "") return { empty: true, value: NaN };
  // A number input holds "" for text it cannot read; badInput tells them apart.
  if (input.validity && input.validity.badInput) return { empty: false, value: NaN };
  return { empty: false, value: Number(text) };
}

export class RequestForm {
  constructor(form, { onSubmit, onLocation, onCheck = () => {}, onMission = () => {} }) {
    this.form = form;
    this.onSubmit = onSubmit;
    this.onMission = onMission;   // in "mission" mode the button sends the mission (mission.js)
    this.mode = "request";
    this.onCheck = onCheck;
    this.limits = NO_LIMITS;
    this.onLocation = onLocation;
    this.inputs = {
      x: form.querySelector("#loc-x"),
      y: form.querySelector("#loc-y"),
      max_robots: form.querySelector("#max-robots"),
      max_cost: form.querySelector("#max-cost"),
      max_time: form.querySelector("#max-time"),
      min_battery: form.querySelector("#min-battery"),
      label: form.querySelector("#label"),
    };
    this.caps = new Map();      // name -> {kind, input, avail, row, error}
    this.defaulted = false;
    this.button = form.querySelector("#send");
    this.result = form.querySelector("#send-result");
    this.forest = null;
    this.timeScale = 1;
    this.busy = false;
    form.addEventListener("submit", (event) => { event.preventDefault(); this.submit(); });
    for (const radio of form.querySelectorAll("input[name=priority]")) {
      radio.addEventListener("change", () => this.explainPriority());
    }
    this.inputs.max_time.addEventListener("input", () => this.explainTime());
    this.explainPriority();
    for (const name of ["x", "y"]) {
      this.inputs[name].addEventListener("input", () => {
        const x = Number(this.inputs.x.value);
        const y = Number(this.inputs.y.value);
        const ready = this.inputs.x.value.trim() !== "" && this.inputs.y.value.trim() !== "";
        this.onLocation(ready && Number.isFinite(x) && Number.isFinite(y) ? [x, y] : null);
      });
    }
    // A field's error goes as soon as the field is changed.
    form.addEventListener("input", (event) => this.clearFor(event.target));
  }

  setForest(forest) {
    this.forest = forest;
  }

  setLimits(limits) {
    if (!limits) return;
    const merged = {};
    for (const [name, bounds] of Object.entries(NO_LIMITS)) merged[name] = { ...bounds, ...(limits[name] || {}) };
    this.limits = merged;
    const attrs = { max_robots: "max_robots", max_cost: "max_cost", max_time: "max_time", min_battery: "min_battery" };
    for (const [field, name] of Object.entries(attrs)) {
      const { min, max } = merged[name];
      if (Number.isFinite(min)) this.inputs[field].min = String(min);
      if (Number.isFinite(max)) this.inputs[field].max = String(max);
    }
    if (Number.isFinite(merged.label.max_length)) this.inputs.label.maxLength = merged.label.max_length;
    for (const cap of this.caps.values()) {
      if (Number.isFinite(merged.count.max)) cap.input.max = String(merged.count.max);
    }
  }

  setUnits(currency, timeScale) {
    this.timeScale = timeScale;
    this.form.querySelector("#cost-unit").textContent = currency;
    this.form.querySelector("#time-unit").textContent = timeScale === 1 ? "s" : "robot s";
    this.explainTime();
  }

  explainPriority() {
    const priority = this.form.querySelector("input[name=priority]:checked")?.value || "balanced";
    this.form.querySelector("#priority-help").textContent = (this.mode === "mission" ? MISSION_PRIORITY_TEXT : PRIORITY_TEXT)[priority];
  }

  // Max time is robot time: say what it is in real time.
  explainTime() {
    const help = this.form.querySelector("#max-time-help");
    const value = Number(this.inputs.max_time.value);
    if (this.timeScale === 1 || !(value > 0)) { help.textContent = ""; return; }
    help.textContent = `= ${fmtDuration(value / this.timeScale)} real time`;
  }

  setLocation([x, y]) {
    this.inputs.x.value = String(x);
    this.inputs.y.value = String(y);
    this.clearError("location");
  }

  // The capabilities the fleet actually has, with how many robots bring each.
  setCapabilities(offers) {
    for (const offer of offers) {
      let cap = this.caps.get(offer.name);
      if (!cap || cap.kind !== offer.kind) {
        if (cap) cap.row.remove();
        cap = this.capRow(offer);
        this.caps.set(offer.name, cap);
        const grid = this.form.querySelector(`#caps-${offer.kind === "actuating" ? "actuating" : "sensing"}`);
        const rows = [...grid.children].filter((row) => row.dataset.cap < offer.name);
        if (rows.length) rows[rows.length - 1].after(cap.row); else grid.prepend(cap.row);
      }
      cap.avail.textContent = `${fmtNumber(offer.idle)} idle of ${fmtNumber(offer.robots)}`;
      cap.idle = offer.idle;
    }
    this.form.querySelector("#caps-empty").hidden = this.caps.size > 0;
    if (!this.defaulted && this.caps.size) {
      // Start from a request the fleet can meet: one robot with the most
      // common idle actuating capability and one with the sensing one.
      this.defaulted = true;
      for (const kind of ["actuating", "sensing"]) {
        const best = offers.filter((o) => o.kind === kind).sort((a, b) => b.idle - a.idle)[0];
        if (best && best.idle > 0) this.caps.get(best.name).input.value = "1";
      }
      this.markWanted();
    }
  }

  capRow(offer) {
    const id = `cap-${offer.name.replace(/[^A-Za-z0-9_-]/g, "_")}`;
    const max = this.limits.count.max;
    const input = el("input", { id, type: "number", min: 0, max: Number.isFinite(max) ? max : null, step: 1, value: 0,
      inputmode: "numeric", "data-cap": offer.name, "aria-describedby": `err-${id} err-capabilities` });
    const avail = el("span", { class: "avail" });
    const error = el("p", { class: "error", id: `err-${id}` });
    const row = el("div", { class: "cap", "data-cap": offer.name },
      el("label", { for: id }, el("span", { class: "name", text: offer.name }), avail), input, error);
    input.addEventListener("input", () => this.markWanted());
    return { kind: offer.kind, input, avail, row, error, idle: 0 };
  }

  markWanted() {
    for (const cap of this.caps.values()) {
      cap.row.classList.toggle("wanted", Number(cap.input.value) >= 1);
    }
  }

  // --- checking ----------------------------------------------------------
  // One fire: its place and the robots it needs with each capability (a
  // request's, and each fire's of a mission).
  readFire() {
    const errors = {};
    const x = readNumber(this.inputs.x);
    const y = readNumber(this.inputs.y);
    if (x.empty && y.empty) errors.location = "Place the fire: click the map, or type x and y.";
    else if (!Number.isFinite(x.value)) errors.location = "x must be a number of metres.";
    else if (!Number.isFinite(y.value)) errors.location = "y must be a number of metres.";
    else if (forestRefusal(this.forest, x.value, y.value)) errors.location = forestRefusal(this.forest, x.value, y.value);

    const sensing = {};
    const actuating = {};
    let most = 0;
    let mostName = null;
    const L = this.limits;
    for (const [name, cap] of this.caps) {
      const count = readNumber(cap.input);
      const value = count.empty ? 0 : count.value;
      if (!Number.isInteger(value) || value < 0 || (Number.isFinite(L.count.max) && value > L.count.max)) {
        errors[`cap:${name}`] = `${name}: a whole number from 0${upTo(L.count.max)}.`;
        continue;
      }
      if (value >= 1) (cap.kind === "actuating" ? actuating : sensing)[name] = value;
      if (value > most) { most = value; mostName = name; }
    }
    if (!this.caps.size) errors.capabilities = "The fleet has not reported its capabilities yet.";
    else if (!Object.keys(sensing).length && !Object.keys(actuating).length
      && !Object.keys(errors).some((k) => k.startsWith("cap:"))) {
      errors.capabilities = "Ask for at least one capability: a count of 1 or more.";
    }
    return { fire: { location: [x.value, y.value], sensing, actuating }, errors, most, mostName };
  }

  read() {
    const { fire, errors, most, mostName } = this.readFire();
    const L = this.limits;
    const maxRobots = readNumber(this.inputs.max_robots);
    if (maxRobots.empty) errors.max_robots = "Max robots is required.";
    else if (!Number.isInteger(maxRobots.value) || !within(maxRobots.value, L.max_robots)) {
      errors.max_robots = `Max robots must be a whole number from ${fmtNumber(L.max_robots.min)}${upTo(L.max_robots.max)}.`;
    } else if (most > maxRobots.value) {
      errors.max_robots = `${mostName} needs ${most} robots, more than max robots allows.`;
    }
    const maxCost = readNumber(this.inputs.max_cost);
    if (maxCost.empty) errors.max_cost = "Max cost is required.";
    else if (!Number.isFinite(maxCost.value) || maxCost.value <= 0) errors.max_cost = "Max cost must be a positive number.";
    else if (!within(maxCost.value, L.max_cost)) errors.max_cost = `Max cost may be at most ${fmtNumber(L.max_cost.max)}.`;
    const { common, errors: more } = this.readCommon(true);
    const task = { ...fire, max_robots: maxRobots.value, max_cost: maxCost.value, ...common };
    return { task, errors: { ...errors, ...more } };
  }

  // What a request and a mission share: max time (a mission's is optional, the
  // last robot's return), min battery, priority, execution, label.
  readCommon(timeRequired) {
    const errors = {};
    const L = this.limits;
    const maxTime = readNumber(this.inputs.max_time);
    if (maxTime.empty) { if (timeRequired) errors.max_time = "Max time is required."; }
    else if (!Number.isFinite(maxTime.value) || maxTime.value <= 0) errors.max_time = "Max time must be a positive number of seconds.";
    else if (!within(maxTime.value, L.max_time)) errors.max_time = `Max time may be at most ${fmtNumber(L.max_time.max)} s.`;
    const battery = readNumber(this.inputs.min_battery);
    const minBattery = battery.empty ? 0 : battery.value;
    if (!Number.isFinite(minBattery) || !within(minBattery, L.min_battery)) {
      errors.min_battery = `Min battery must be a percentage from ${fmtNumber(L.min_battery.min)} to ${fmtNumber(L.min_battery.max)}.`;
    }
    const label = this.inputs.label.value.trim();
    if (label.length > L.label.max_length) errors.label = `The label may have at most ${fmtNumber(L.label.max_length)} characters.`;
    const common = {
      max_time: maxTime.empty ? null : maxTime.value,
      min_battery: minBattery,
      priority: this.form.querySelector("input[name=priority]:checked")?.value || "balanced",
      execution: this.form.querySelector("input[name=execution]:checked")?.value || "parallel",
    };
    if (label) common.label = label;
    return { common, errors };
  }

  // The errors of a check, beside their fields and whole beside the button.
  refuse(errors) {
    const messages = Object.values(errors);
    if (!messages.length) return false;
    this.showErrors(errors);
    // Beside the button too, whole: the field may be out of sight in a short window.
    this.setResult(`Check the field${messages.length === 1 ? "" : "s"} marked in red: ${messages[0]}`
      + (messages.length > 1 ? ` (and ${messages.length - 1} more)` : ""), "error");
    return true;
  }

  async submit() {
    this.onCheck();
    this.clearErrors();
    this.setResult("", null);
    if (this.mode === "mission") {
      await this.onMission();
      return;
    }
    const { task, errors } = this.read();
    if (this.refuse(errors)) return;
    await this.onSubmit(task);
  }

  // "request" (one fire) or "mission" (several): the fields a mission has not are hidden.
  setMode(mode) {
    const next = mode === "mission" ? "mission" : "request";
    if (next !== this.mode) {
      // Max time is each one's own: a request's bounds its coalition, a mission's
      // (optional, empty at first) the last robot's return.
      const kept = this.inputs.max_time.value;
      this.inputs.max_time.value = this.otherMaxTime ?? (next === "mission" ? "" : kept);
      this.otherMaxTime = kept;
      this.explainTime();
    }
    this.mode = next;
    this.explainPriority();
    document.body.dataset.send = this.mode;
    if (!this.busy) this.setBusy(false);
  }

  // While a send (of "the request" or "the mission") is not settled: the
  // button's word, the line under it and "Stop checking". False once settled.
  showPending(submission, what) {
    this.form.querySelector("#stop-checking").hidden = !["unconfirmed", "not-sent-yet"].includes(submission.state);
    const pending = pendingLine(submission, what, sentence(humanize(submission.detail || "")));
    if (!pending) return false;
    this.setBusy(true, pending.button);
    this.setResult(pending.text, "pending");
    return true;
  }

  // While a send is not settled the button stays off: pressing it again
  // would be a second request.
  setBusy(busy, text = this.mode === "mission" ? "Send the Mission" : "Send a Request") {
    this.busy = busy;
    this.button.disabled = busy;
    this.button.textContent = text;
  }

  // --- errors beside the fields -----------------------------------------
  targetsOf(field) {
    if (field === "location") return [this.inputs.x, this.inputs.y];
    if (field === "capabilities") return [...this.caps.values()].map((c) => c.input);
    if (field.startsWith("cap:")) {
      const cap = this.caps.get(field.slice(4));
      return cap ? [cap.input] : [];
    }
    return this.inputs[field] ? [this.inputs[field]] : [];
  }

  errorSlot(field) {
    if (field.startsWith("cap:")) return this.caps.get(field.slice(4))?.error ?? null;
    return this.form.querySelector(`[data-error-for="${field}"]`);
  }

  showErrors(errors) {
    let first = null;
    for (const [field, message] of Object.entries(errors)) {
      const slot = this.errorSlot(field);
      if (slot) slot.textContent = message;
      for (const input of this.targetsOf(field)) {
        input.setAttribute("aria-invalid", "true");
        first = first || input;
      }
    }
    if (first) first.focus();
  }

  // The IaaS names the field first ("max_cost: input should be ..."; "location is missing").
  // Beside its field, the sentence loses the name and speaks the form's words.
  showServerError(detail) {
    const match = /^(location|sensing|actuating|max_robots|max_cost|max_time|min_battery|priority|execution|label|input)(?:\.([^\s:[]+))?(?:\[\d+\])?(:| is )/.exec(detail);
    let field = "form";
    let text = detail;
    if (match) {
      const [whole, name, sub, sep] = match;
      if ((name === "sensing" || name === "actuating") && sub && this.caps.has(sub)) field = `cap:${sub}`;
      else if (name === "sensing" || name === "actuating" || (name === "input" && /capabilit/.test(detail))) field = "capabilities";
      else if (FIELDS.includes(name)) field = name;
      if (field !== "form" && sep === ":") text = detail.slice(whole.length);
    }
    this.showErrors({ [field]: sentence(humanize(text)) });
  }

  clearError(field) {
    const slot = this.errorSlot(field);
    if (slot) slot.textContent = "";
    for (const input of this.targetsOf(field)) input.removeAttribute("aria-invalid");
  }

  clearFor(input) {
    if (input === this.inputs.x || input === this.inputs.y) this.clearError("location");
    else if (input.dataset && input.dataset.cap) { this.clearError(`cap:${input.dataset.cap}`); this.clearError("capabilities"); }
    else {
      for (const [field, candidate] of Object.entries(this.inputs)) {
        if (candidate === input) this.clearError(field);
      }
    }
  }

  clearErrors() {
    for (const slot of this.form.querySelectorAll(".error")) slot.textContent = "";
    for (const input of this.form.querySelectorAll("[aria-invalid]")) input.removeAttribute("aria-invalid");
  }

  setResult(text, kind) {
    // The kind first: the words never show in the colour of the line before.
    if (kind) this.result.dataset.kind = kind; else delete this.result.dataset.kind;
    delete this.result.dataset.mission;   // the line is about something else now (mission.js say)
    this.result.textContent = text;
  }
}
