// Small helpers shared by the page's modules: DOM and SVG building, formatting.

const SVG_NS = "http://www.w3.org/2000/svg";

export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  setAttrs(node, attrs);
  node.append(...children.filter((c) => c !== null && c !== undefined && c !== false));
  return node;
}

export function svg(tag, attrs = {}, ...children) {
  const node = document.createElementNS(SVG_NS, tag);
  setAttrs(node, attrs);
  node.append(...children.filter((c) => c !== null && c !== undefined && c !== false));
  return node;
}

function setAttrs(node, attrs) {
  for (const [key, value] of Object.entries(attrs)) {
    if (value === null || value === undefined || value === false) continue;
    if (key === "text") node.textContent = value;
    else if (key === "class") node.setAttribute("class", value);
    else node.setAttribute(key, value === true ? "" : String(value));
  }
}

export const $ = (id) => document.getElementById(id);

export function fmtNumber(value, digits = 0) {
  if (value === null || value === undefined || !Number.isFinite(value)) return "–";
  return value.toLocaleString("en-US", { minimumFractionDigits: digits, maximumFractionDigits: digits });
}

// The page's one duration format: "42 s", "4 min 05 s", "2 h 05 min".
// The server's alerts use the same (live.py fmt_duration).
export function fmtDuration(seconds) {
  if (seconds === null || seconds === undefined || !Number.isFinite(seconds)) return "–";
  if (seconds < 1) return "under 1 s";
  if (seconds < 60) return `${Math.round(seconds)} s`;
  if (seconds < 3600) {
    const whole = Math.round(seconds);
    return `${Math.floor(whole / 60)} min ${String(whole % 60).padStart(2, "0")} s`;
  }
  const minutes = Math.round(seconds / 60);
  return `${Math.floor(minutes / 60)} h ${String(minutes % 60).padStart(2, "0")} min`;
}

// The same, for an age: "12 s ago".
export function fmtAge(seconds) {
  if (!Number.isFinite(seconds)) return "–";
  return seconds < 1 ? "just now" : `${fmtDuration(seconds)} ago`;
}

export function fmtClock(when) {
  const date = typeof when === "number" ? new Date(when * 1000) : new Date(when);
  if (Number.isNaN(date.getTime())) return "";
  return date.toLocaleTimeString("en-GB", { hour12: false });
}

export function fmtPoint(point) {
  if (!Array.isArray(point) || point.length !== 2) return "";
  return `(${fmtNumber(point[0])}, ${fmtNumber(point[1])})`;
}

// Seconds since the epoch of an ISO time from an IaaS.
export function epoch(iso) {
  const t = Date.parse(iso);
  return Number.isNaN(t) ? NaN : t / 1000;
}

// A "nice" step (1, 2, 2.5 or 5 times a power of ten) of at least `raw`.
export function niceStep(raw) {
  const power = 10 ** Math.floor(Math.log10(raw));
  return [1, 2, 2.5, 5, 10].map((m) => m * power).find((s) => s >= raw * (1 - 1e-12)) ?? raw;
}

// "Nice" axis ticks: about `count` round numbers within [lo, hi].
export function ticks(lo, hi, count = 5) {
  if (!(hi > lo)) return [lo];
  const step = niceStep((hi - lo) / count);
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) out.push(+v.toFixed(10));
  return out;
}

// An axis for `values` whose ticks cover every value: it starts and ends on a
// tick, so no point lies beyond the labelled range. At least three ticks.
export function niceAxis(values, count = 4, floor = 0) {
  let lo = Math.min(...values);
  let hi = Math.max(...values);
  if (!(hi > lo)) {
    const pad = Math.max(Math.abs(hi) * 0.1, 1);
    lo -= pad;
    hi += pad;
  }
  const span = hi - lo;
  lo = Math.max(floor, lo - span * 0.05);
  hi += span * 0.05;
  const step = niceStep((hi - lo) / count);
  const start = Math.max(floor, Math.floor(lo / step + 1e-9) * step);
  const end = Math.ceil(hi / step - 1e-9) * step;
  const out = [];
  for (let v = start; v <= end + step * 1e-9; v += step) out.push(+v.toFixed(10));
  return { lo: out[0], hi: out[out.length - 1], ticks: out };
}

// The decimals that tell each of `values` (evenly spaced ticks) from the next, at most 3:
// ticks half a second apart are 5.0 and 5.5, not 5 and 6.
export function tickDigits(values) {
  if (values.length < 2) return 0;
  const step = Math.abs(values[1] - values[0]);
  for (let digits = 0; digits < 3; digits++) {
    const scaled = step * 10 ** digits;
    if (Math.abs(scaled - Math.round(scaled)) < 1e-9) return digits;
  }
  return 3;
}

export function sentence(text) {
  const t = String(text || "").trim();
  if (!t) return "";
  const s = t.charAt(0).toUpperCase() + t.slice(1);
  return /[.!?]$/.test(s) ? s : `${s}.`;
}

// The task's field names as the form shows them, in the IaaS's sentences.
const FIELD_NAMES = {
  max_time: "max time", max_cost: "max cost", max_robots: "max robots", min_battery: "min battery",
  location: "location", sensing: "sensing", actuating: "actuating", priority: "priority",
  execution: "execution", label: "label",
};

export function humanize(text) {
  return String(text || "").replace(/\b(max_time|max_cost|max_robots|min_battery)\b/g, (name) => FIELD_NAMES[name]);
}

// A request's states, from the server's config (robocloud.domain.request, the one
// source): filled in place by setStates, so every module's import sees them.
export const FINAL_STATES = new Set();
export const ACTIVE_STATES = [];
export const REQUEST_STATES = [];

export function setStates(states) {
  if (!states || REQUEST_STATES.length) return;
  REQUEST_STATES.push(...states.all);
  ACTIVE_STATES.push(...states.all.filter((s) => !states.final.includes(s)));
  for (const s of states.final) FINAL_STATES.add(s);
}
export const STATUSES = ["idle", "reserved", "busy", "charging", "offline"];
export const PRIORITY = { balanced: "balanced", time: "time critical", cost: "cost critical" };

// Clouds' colours come from the server (stable for a cloud's name); this is
// for a cloud it has not described yet.
const colours = new Map();
export function setCloudColours(clouds) {
  for (const cloud of clouds) colours.set(cloud.name, cloud.colour);
}
export function cloudColour(cloud) {
  return colours.get(cloud) || "#64748b";
}
