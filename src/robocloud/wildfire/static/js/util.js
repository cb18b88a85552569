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

export function fmtNumber(value, digits = 0) {
  if (value === null || value === undefined || !Number.isFinite(value)) return "–";
  return value.toLocaleString("en-US", { minimumFractionDigits: digits, maximumFractionDigits: digits });
}

export function fmtDuration(seconds) {
  if (seconds === null || seconds === undefined || !Number.isFinite(seconds)) return "–";
  if (seconds < 60) return `${fmtNumber(seconds, seconds < 10 ? 1 : 0)} s`;
  const minutes = Math.floor(seconds / 60);
  const rest = Math.round(seconds - minutes * 60);
  if (minutes < 60) return rest ? `${minutes} min ${rest} s` : `${minutes} min`;
  const hours = Math.floor(minutes / 60);
  return `${hours} h ${minutes % 60} min`;
}

// "4m 30s": for the small stat boxes.
export function fmtShortDuration(seconds) {
  if (seconds === null || seconds === undefined || !Number.isFinite(seconds)) return "–";
  if (seconds < 60) return `${fmtNumber(seconds, seconds < 10 ? 1 : 0)}s`;
  const minutes = Math.floor(seconds / 60);
  if (minutes < 60) return `${minutes}m ${String(Math.round(seconds - minutes * 60)).padStart(2, "0")}s`;
  return `${Math.floor(minutes / 60)}h ${String(minutes % 60).padStart(2, "0")}m`;
}

export function fmtClock(iso) {
  const date = new Date(iso);
  if (Number.isNaN(date.getTime())) return "";
  return date.toLocaleTimeString("en-GB", { hour12: false });
}

export function fmtPoint(point) {
  if (!Array.isArray(point) || point.length !== 2) return "";
  return `(${fmtNumber(point[0])}, ${fmtNumber(point[1])})`;
}

// "Nice" axis ticks: about `count` round numbers covering [lo, hi].
export function ticks(lo, hi, count = 5) {
  if (!(hi > lo)) return [lo];
  const raw = (hi - lo) / count;
  const power = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 2.5, 5, 10].map((m) => m * power).find((s) => s >= raw) ?? raw;
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) out.push(+v.toFixed(10));
  return out;
}

// Colour-blind-safe colours (Okabe-Ito and Tol) for clouds, in order of first sight.
const CLOUD_COLOURS = ["#0072B2", "#009E73", "#CC79A7", "#8C6D1F", "#56B4E9", "#6A3D9A", "#117733", "#882255"];
const cloudColours = new Map();

export function cloudColour(cloud) {
  if (!cloudColours.has(cloud)) {
    cloudColours.set(cloud, CLOUD_COLOURS[cloudColours.size % CLOUD_COLOURS.length]);
  }
  return cloudColours.get(cloud);
}

// Clouds get their colours in name order, so every page shows the same ones.
export function assignCloudColours(clouds) {
  for (const cloud of [...clouds].sort()) cloudColour(cloud);
}

export const FINAL_STATES = new Set(["completed", "rejected", "canceled", "failed"]);
