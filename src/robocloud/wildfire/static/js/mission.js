// A mission: several fires planned as one (docs/model.md, "A mission"). The
// operator places a fire and chooses its needs with the request form's own
// fields (form.js readFire), adds it to the list, says which fire waits for
// which ("fire-3 after fire-1"), optionally where the robots end, and sends
// the whole as ONE mission: POST /api/missions with an Idempotency-Key kept
// for every retry (sender.js, the rules of a request's send).

import { forestRefusal } from "./form.js";
import { Sender } from "./sender.js";
import { $, el, fmtNumber, fmtPoint, humanize, sentence } from "./util.js";

// A fire's colour, the same on the map, in the list and in the Gantt chart
// (Okabe-Ito and Tol's colour-blind-safe colours, by the fire's place in the mission).
const TASK_COLOURS = ["#E69F00", "#0072B2", "#009E73", "#CC79A7", "#D55E00", "#56B4E9", "#882255", "#999933", "#332288", "#44AA99"];

export function taskColour(index) {
  return TASK_COLOURS[((index % TASK_COLOURS.length) + TASK_COLOURS.length) % TASK_COLOURS.length];
}

export function needsOf(task) {
  return Object.entries({ ...(task.actuating || {}), ...(task.sensing || {}) })
    .map(([name, count]) => `${name}×${count}`).join(", ");
}

// The precedence pairs [before, after] in a cycle, if any (each fire waits for itself, in the end).
export function cycleIn(ids, pairs) {
  const waitsFor = new Map(ids.map((id) => [id, []]));
  for (const [before, after] of pairs) waitsFor.get(after)?.push(before);
  const state = new Map();
  const visit = (id) => {
    if (state.get(id) === "done") return false;
    if (state.get(id) === "open") return true;
    state.set(id, "open");
    const found = waitsFor.get(id).some(visit);
    state.set(id, "done");
    return found;
  };
  return ids.some(visit);
}

export class MissionBuilder {
  constructor({ api, form, onChange, onSent, onAdded = () => {} }) {
    this.form = form;
    this.onAdded = onAdded;       // a fire joined the list: the next one is placed afresh
    this.onChange = onChange;     // the fires or the end changed: the map draws them
    this.onSent = onSent;         // the IaaS has the mission: follow it
    this.fires = [];              // {id, location, sensing, actuating, duration}
    this.orders = [];             // [before, after]
    this.next = 1;
    this.sender = new Sender({ api: { send: (body, key) => api.sendMission(body, key) }, onChange: (s) => this.showSend(s) });
    $("add-fire").addEventListener("click", () => this.addFire());
    $("add-order").addEventListener("click", () => this.addOrder());
    $("end-on").addEventListener("change", () => this.changed());
    for (const id of ["end-x", "end-y"]) {
      $(id).addEventListener("input", () => {
        $("end-on").checked = $("end-x").value.trim() !== "" && $("end-y").value.trim() !== "";
        this.changed();
      });
    }
    this.render();
  }

  // --- the list ------------------------------------------------------------
  addFire() {
    this.form.clearErrors();
    this.form.setResult("", null);
    const { fire, errors } = this.form.readFire();
    const duration = $("fire-duration").value.trim();
    if (duration !== "" && !(Number(duration) >= 0 && Number.isFinite(Number(duration)))) {
      errors.mission = "The work time of a fire must be a number of seconds, 0 or more.";
    }
    if (this.form.refuse(errors)) return;
    const entry = { id: `fire-${this.next++}`, ...fire };
    if (duration !== "") entry.duration = Number(duration);
    this.fires.push(entry);
    $("fire-duration").value = "";
    this.form.inputs.x.value = "";
    this.form.inputs.y.value = "";
    this.onAdded(entry);
    this.form.setResult(`${entry.id} added at ${fmtPoint(entry.location)}: ${needsOf(entry)}. Place the next fire, or send the mission.`, "info");
    this.changed();
  }

  removeFire(id) {
    this.fires = this.fires.filter((f) => f.id !== id);
    this.orders = this.orders.filter(([a, b]) => a !== id && b !== id);
    this.changed();
  }

  addOrder() {
    const after = $("order-after").value;
    const before = $("order-before").value;
    let error = "";
    if (!after || !before) error = "Add two fires first: then one can wait for the other.";
    else if (after === before) error = `${after} cannot wait for itself.`;
    else if (this.orders.some(([a, b]) => a === before && b === after)) error = `${after} already waits for ${before}.`;
    else if (cycleIn(this.fires.map((f) => f.id), [...this.orders, [before, after]])) {
      error = `${after} after ${before} would make a circle: some fire would wait for itself.`;
    }
    if (error) {
      this.form.showErrors({ mission: error });
      return;
    }
    this.form.clearError("mission");
    this.orders.push([before, after]);
    this.changed();
  }

  end() {
    if (!$("end-on").checked) return null;
    const x = Number($("end-x").value);
    const y = Number($("end-y").value);
    return $("end-x").value.trim() !== "" && $("end-y").value.trim() !== "" && Number.isFinite(x) && Number.isFinite(y) ? [x, y] : null;
  }

  setEnd([x, y]) {
    $("end-x").value = String(x);
    $("end-y").value = String(y);
    $("end-on").checked = true;
    this.changed();
  }

  changed() {
    this.render();
    this.onChange(this);
  }

  render() {
    const list = $("mission-fires");
    list.replaceChildren(...this.fires.map((fire, i) => {
      const swatch = el("span", { class: "task-dot", "aria-hidden": "true", text: String(i + 1) });
      swatch.style.background = taskColour(i);
      const remove = el("button", { type: "button", class: "remove", "aria-label": `Remove ${fire.id}`, text: "×" });
      remove.addEventListener("click", () => this.removeFire(fire.id));
      const work = fire.duration === undefined ? "" : ` · ${fmtNumber(fire.duration)} s`;
      return el("li", { "data-task": fire.id }, swatch,
        el("span", { class: "what" }, el("b", { text: fire.id }), ` ${fmtPoint(fire.location)} · ${needsOf(fire)}${work}`), remove);
    }));
    $("mission-fires-empty").hidden = this.fires.length > 0;
    for (const id of ["order-after", "order-before"]) {
      const select = $(id);
      const value = select.value;
      select.replaceChildren(...this.fires.map((f) => el("option", { value: f.id, text: f.id })));
      if (this.fires.some((f) => f.id === value)) select.value = value;
      else if (id === "order-after" && this.fires.length > 1) select.value = this.fires[this.fires.length - 1].id;
    }
    $("orders").hidden = this.fires.length < 2;
    $("mission-orders").replaceChildren(...this.orders.map(([before, after]) => {
      const remove = el("button", { type: "button", class: "remove", "aria-label": `Remove: ${after} after ${before}`, text: "×" });
      remove.addEventListener("click", () => {
        this.orders = this.orders.filter(([a, b]) => !(a === before && b === after));
        this.changed();
      });
      return el("li", { "data-before": before, "data-after": after }, el("span", { text: `${after} after ${before} is out` }), remove);
    }));
  }

  // --- sending ---------------------------------------------------------------
  read() {
    const { common, errors } = this.form.readCommon(false);
    if (!this.fires.length) errors.mission = "Add at least one fire: place it, choose its needs, then Add this fire.";
    const end = this.end();
    if ($("end-on").checked && !end) errors.mission = "The end place needs x and y, in metres.";
    else if (end && forestRefusal(this.form.forest, end[0], end[1])) {
      errors.mission = forestRefusal(this.form.forest, end[0], end[1]).replace("The fire", "The end place");
    }
    const mission = {
      tasks: this.fires.map(({ id, location, sensing, actuating, duration }) => (
        duration === undefined ? { id, location, sensing, actuating } : { id, location, sensing, actuating, duration })),
      precedence: this.orders.map((pair) => [...pair]),
      end,
      ...common,
    };
    return { mission, errors };
  }

  async submit() {
    const { mission, errors } = this.read();
    if (this.form.refuse(errors)) return;
    await this.sender.submit(mission);
  }

  showSend(submission) {
    const form = this.form;
    if (form.showPending(submission, "mission")) return;
    const detail = sentence(humanize(submission.detail || ""));
    switch (submission.state) {
      case "confirmed": {
        form.setBusy(false);
        const mission = submission.request;
        this.say(mission, true);
        this.fires = [];
        this.orders = [];
        this.next = 1;
        this.changed();
        this.onSent(mission);
        break;
      }
      case "refused":
        form.setBusy(false);
        form.showErrors({ [this.fieldOf(submission.detail)]: detail });
        form.setResult(`The mission was refused: ${detail} Nothing was sent to the robots.`, "error");
        break;
      case "stopped":
        form.setBusy(false);
        form.setResult(submission.maybeDelivered
          ? "Stopped checking. The mission may have reached the IaaS: if it did, it will show under Mission."
          : "Stopped. No IaaS received the mission, so nothing was sent; you can send it again.", "pending");
        break;
      default:
        form.setBusy(false);
    }
  }

  // The send's line follows its mission, in the IaaS's words: green only once
  // the IaaS says the plan is being carried out, so a rejection is never green.
  say(mission, sent = false) {
    const line = this.form.result;
    if (!sent && line.dataset.mission !== mission.id) return;
    const name = mission.label ? `${mission.id} (“${mission.label}”)` : mission.id;
    const robots = ((mission.plan && mission.plan.robots) || []).length;
    switch (mission.state) {
      case "rejected":
      case "failed":
        this.form.setResult(`${name} was ${mission.state}: ${sentence(humanize(mission.reason || "no reason given"))}`, "error");
        break;
      case "canceled":
        this.form.setResult(`${name} was canceled.`, "info");
        break;
      case "underway":
        this.form.setResult(`Sent ${name}: underway, plan ${mission.plan ? mission.plan.version : "–"}, ${robots} robot${robots === 1 ? "" : "s"}.`, "ok");
        break;
      case "completed":
        this.form.setResult(`Sent ${name}: completed.`, "ok");
        break;
      default:
        this.form.setResult(`Sent ${name}: the IaaS has it (${mission.state}) and is planning…`, "info");
    }
    line.dataset.mission = mission.id;
  }

  // The IaaS names the field ("tasks[1].location: ..."): its fire is marked in the list.
  fieldOf(detail) {
    const match = /^tasks\[(\d+)\]/.exec(detail || "");
    const fire = match && this.fires[Number(match[1])];
    for (const row of $("mission-fires").children) row.toggleAttribute("data-invalid", Boolean(fire && row.dataset.task === fire.id));
    return "mission";
  }

  stop() {
    this.sender.stop();
  }
}
