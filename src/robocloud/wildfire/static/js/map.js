// The forest map: robots coloured by cloud and shaped by state (greyed with
// their age when stale), the fire the operator places, the selected request's
// coalition with paths to its fire. Zoom and pan with the wheel, a pinch, a
// drag, the buttons or the keyboard; filters by cloud, status and capability.
// Inline SVG, y up; robots keep their size on screen whatever the zoom.
//
// What a click does is one rule, said on the page: in "Place fire" mode (the
// default) a click places the fire wherever it lands, on a robot too; a
// robot's details come with Shift+click, or in "Inspect robots" mode, where a
// click opens the card of the nearest robot and never moves the fire. So a
// crowded forest never turns a click meant for the fire into a robot's card.

import { cloudColour, fmtAge, fmtNumber, STATUSES, svg, ticks } from "./util.js";

// Room beside the plot for the axis labels, whole at a phone's larger font.
export const AREA = { left: 104, top: 14, right: 978, bottom: 888 };  // viewBox 0 0 1024 930
const SIDE = AREA.right - AREA.left;   // the plot area is square
const MAX_ZOOM = 32;
const DRAG_PX = 5;                     // a press that moves less is a click
const PICK_RADIUS = 30;                // viewBox units: how near a click must be to inspect a robot

function shapeFor(status) {
  switch (status) {
    case "reserved": return svg("rect", { class: "shape", x: -11, y: -11, width: 22, height: 22, rx: 3 });
    case "busy": return svg("path", { class: "shape", d: "M0 -15 L14 10 L-14 10 Z" });
    case "charging": return svg("path", { class: "shape", d: "M0 -15 L15 0 L0 15 L-15 0 Z" });
    case "offline": return svg("circle", { class: "shape", r: 11 });
    default: return svg("circle", { class: "shape", r: 12.5 });
  }
}

export class ForestMap {
  constructor(element, { onPlace, onRobot, onEnd = () => {} }) {
    this.svg = element;
    this.onPlace = onPlace;
    this.onEnd = onEnd;           // "End place" mode: a mission's end (mission.js)
    this.overlays = [];           // drawn again with the map (routes.js)
    this.onRobot = onRobot;
    this.forest = { x0: 0, y0: 0, x1: 2000, y1: 2000 };
    this.view = { cx: 1000, cy: 1000, k: 1 };
    this.robots = new Map();      // id -> {group, shape, status, robot}
    this.fire = null;             // [x, y] or null
    this.selection = null;        // {location, robots: Set, active}
    this.filter = { cloud: "", status: "", capability: "" };
    this.mode = "fire";           // "fire", "inspect" or "end": what a click does
    this.layers = {};
    const clip = svg("clipPath", { id: "map-clip" },
      svg("rect", { x: AREA.left, y: AREA.top, width: SIDE, height: SIDE, rx: 6 }));
    this.svg.append(svg("defs", {}, clip));
    // Robots, then the coalition above them, then the fire above everything.
    for (const name of ["ground", "grid", "mission", "robots", "links", "coalition", "target", "fire"]) {
      this.layers[name] = svg("g", { class: name });
      if (name !== "grid") this.layers[name].setAttribute("clip-path", "url(#map-clip)");
      this.svg.append(this.layers[name]);
    }
    this.pointers = new Map();
    this.gesture = null;
    this.svg.addEventListener("pointerdown", (e) => this.pointerDown(e));
    this.svg.addEventListener("pointermove", (e) => this.pointerMove(e));
    this.svg.addEventListener("pointerup", (e) => this.pointerUp(e));
    this.svg.addEventListener("pointercancel", (e) => this.pointers.delete(e.pointerId));
    this.svg.addEventListener("wheel", (e) => this.wheel(e), { passive: false });
    this.svg.addEventListener("keydown", (e) => this.key(e));
    this.svg.addEventListener("mouseover", (e) => this.hover(e));
    this.ageOf = () => null;
    this.scale = "1.00";
    this.redraw();
  }

  setForest(forest) {
    const same = ["x0", "y0", "x1", "y1"].every((k) => forest[k] === this.forest[k]);
    this.forest = { ...forest };
    if (!same) this.reset();
  }

  // --- the view ------------------------------------------------------------
  baseSide() {
    const f = this.forest;
    return Math.max(f.x1 - f.x0, f.y1 - f.y0);
  }

  window() {
    const side = this.baseSide() / this.view.k;
    const { cx, cy } = this.view;
    return { x0: cx - side / 2, x1: cx + side / 2, y0: cy - side / 2, y1: cy + side / 2, side };
  }

  toScreen([x, y]) {
    const w = this.window();
    return [AREA.left + ((x - w.x0) / w.side) * SIDE, AREA.top + ((w.y1 - y) / w.side) * SIDE];
  }

  toWorld(sx, sy) {
    const w = this.window();
    return [w.x0 + ((sx - AREA.left) / SIDE) * w.side, w.y1 - ((sy - AREA.top) / SIDE) * w.side];
  }

  inForest([x, y]) {
    const f = this.forest;
    return x >= f.x0 && x <= f.x1 && y >= f.y0 && y <= f.y1;
  }

  // The view's centre stays over the forest, so some forest is always in sight.
  setView(cx, cy, k) {
    const f = this.forest;
    const zoom = Math.min(MAX_ZOOM, Math.max(1, k));
    this.view = {
      k: zoom,
      cx: zoom === 1 ? (f.x0 + f.x1) / 2 : Math.min(f.x1, Math.max(f.x0, cx)),
      cy: zoom === 1 ? (f.y0 + f.y1) / 2 : Math.min(f.y1, Math.max(f.y0, cy)),
    };
    this.svg.dataset.zoom = this.view.k.toFixed(2);
    this.redraw();
  }

  zoomAt(sx, sy, factor) {
    const [wx, wy] = this.toWorld(sx, sy);
    const k = Math.min(MAX_ZOOM, Math.max(1, this.view.k * factor));
    // Keep the forest point under (sx, sy) where it is.
    const side = this.baseSide() / k;
    const cx = wx - ((sx - AREA.left) / SIDE - 0.5) * side;
    const cy = wy + ((sy - AREA.top) / SIDE - 0.5) * side;
    this.setView(cx, cy, k);
  }

  zoomBy(factor) {
    this.zoomAt(AREA.left + SIDE / 2, AREA.top + SIDE / 2, factor);
  }

  panBy(dsx, dsy) {
    const perPx = this.window().side / SIDE;
    this.setView(this.view.cx - dsx * perPx, this.view.cy + dsy * perPx, this.view.k);
  }

  reset() {
    this.setView(0, 0, 1);
  }

  visibleArea() {
    const w = this.window();
    return `x ${fmtNumber(w.x0)}–${fmtNumber(w.x1)} m, y ${fmtNumber(w.y0)}–${fmtNumber(w.y1)} m`;
  }

  redraw() {
    this.svg.classList.add("instant");
    this.scale = this.robotScale();
    this.drawGround();
    for (const entry of this.robots.values()) this.place(entry);
    this.drawFire();
    this.drawSelection();
    for (const overlay of this.overlays) overlay.draw();
    requestAnimationFrame(() => requestAnimationFrame(() => this.svg.classList.remove("instant")));
  }

  drawGround() {
    const { ground, grid } = this.layers;
    const [fx0, fy1] = this.toScreen([this.forest.x0, this.forest.y1]);
    const [fx1, fy0] = this.toScreen([this.forest.x1, this.forest.y0]);
    ground.replaceChildren(
      svg("rect", { class: "outside", x: AREA.left, y: AREA.top, width: SIDE, height: SIDE }),
      svg("rect", { class: "ground", x: fx0, y: fy1, width: fx1 - fx0, height: fy0 - fy1 }),
      this.trees(),
    );
    grid.replaceChildren();
    const w = this.window();
    const xs = ticks(w.x0, w.x1, 8);
    const ys = ticks(w.y0, w.y1, 8);
    const gridLines = svg("g", { "clip-path": "url(#map-clip)" });
    grid.append(gridLines);
    xs.forEach((x, i) => {
      const [sx] = this.toScreen([x, 0]);
      gridLines.append(svg("line", { x1: sx, x2: sx, y1: AREA.top, y2: AREA.bottom }));
      if (i % 2 === 0 && sx >= AREA.left - 1 && sx <= AREA.right + 1) {
        grid.append(svg("text", { x: sx, y: AREA.bottom + 30, "text-anchor": "middle", text: fmtNumber(x) }));
      }
    });
    ys.forEach((y, i) => {
      const [, sy] = this.toScreen([0, y]);
      gridLines.append(svg("line", { x1: AREA.left, x2: AREA.right, y1: sy, y2: sy }));
      if (i % 2 === 0 && sy >= AREA.top - 1 && sy <= AREA.bottom + 1) {
        grid.append(svg("text", { x: AREA.left - 8, y: sy + 8, "text-anchor": "end", text: fmtNumber(y) }));
      }
    });
    grid.append(svg("rect", { class: "frame", x: AREA.left, y: AREA.top, width: SIDE, height: SIDE, rx: 6 }));
  }

  // Decorative canopy over the forest, the same on every page.
  trees() {
    const group = svg("g", { class: "trees", "aria-hidden": "true" });
    const f = this.forest;
    const scale = SIDE / this.window().side;
    let seed = 7;
    const rand = () => { seed = (seed * 16807) % 2147483647; return seed / 2147483647; };
    for (let i = 0; i < 170; i++) {
      const x = f.x0 + rand() * (f.x1 - f.x0);
      const y = f.y0 + rand() * (f.y1 - f.y0);
      const r = (6 + rand() * 12) * (this.baseSide() / SIDE) * scale;
      const [sx, sy] = this.toScreen([x, y]);
      if (sx < AREA.left - r || sx > AREA.right + r || sy < AREA.top - r || sy > AREA.bottom + r) continue;
      group.append(svg("circle", { cx: sx.toFixed(1), cy: sy.toFixed(1), r: Math.min(r, 400).toFixed(1) }));
    }
    return group;
  }

  // --- robots ----------------------------------------------------------------
  upsert(robot) {
    let entry = this.robots.get(robot.id);
    if (!entry) {
      const group = svg("g", { class: "robot", "data-robot": robot.id }, svg("title"));
      entry = { group, shape: null, status: null, robot, halo: null };
      this.robots.set(robot.id, entry);
      this.layers.robots.append(group);
    }
    entry.robot = robot;
    if (this.robotScale() !== this.scale) this.redraw();
    const status = STATUSES.includes(robot.status) ? robot.status : "offline";
    if (status !== entry.status) {
      const shape = shapeFor(status);
      if (entry.shape) entry.shape.replaceWith(shape); else entry.group.append(shape);
      entry.shape = shape;
      entry.status = status;
      entry.group.dataset.status = status;
    }
    const stale = robot.heard !== null && robot.heard !== undefined;
    entry.group.classList.toggle("stale", stale);
    entry.group.classList.toggle(status, true);
    for (const s of STATUSES) if (s !== status) entry.group.classList.remove(s);
    entry.group.dataset.cloud = robot.cloud;
    entry.shape.setAttribute("fill", cloudColour(robot.cloud));
    entry.shape.setAttribute("stroke", status === "offline" ? cloudColour(robot.cloud) : "#ffffff");
    this.place(entry);
    this.filterOne(entry);
  }

  remove(id) {
    const entry = this.robots.get(id);
    if (!entry) return;
    entry.group.remove();
    this.robots.delete(id);
  }

  place(entry) {
    const [sx, sy] = this.toScreen([entry.robot.x, entry.robot.y]);
    entry.group.style.transform = `translate(${sx.toFixed(1)}px, ${sy.toFixed(1)}px) scale(${this.scale})`;
  }

  // A crowded forest draws its robots smaller; zooming in brings them back.
  robotScale() {
    const n = this.robots.size;
    const base = n > 600 ? 0.62 : n > 250 ? 0.8 : 1;
    return Math.min(1, base * Math.sqrt(this.view.k)).toFixed(2);
  }

  describe(robot) {
    const age = this.ageOf(robot);
    return `${robot.id} · ${robot.cloud} · ${robot.status} · battery ${fmtNumber(robot.battery)}%`
      + ` · ${(robot.capabilities || []).join(", ")}${robot.request ? ` · ${robot.request}` : ""}`
      + (age === null ? "" : ` · stale, last heard ${fmtAge(age)}`);
  }

  hover(event) {
    const group = event.target.closest && event.target.closest(".robot");
    const entry = group && this.robots.get(group.dataset.robot);
    if (entry) entry.group.querySelector("title").textContent = this.describe(entry.robot);
  }

  // --- filters -------------------------------------------------------------
  setFilter(filter) {
    this.filter = { ...filter };
    for (const entry of this.robots.values()) this.filterOne(entry);
  }

  matches(robot) {
    const f = this.filter;
    if (f.cloud && robot.cloud !== f.cloud) return false;
    if (f.status === "stale") { if (robot.heard === null || robot.heard === undefined) return false; }
    else if (f.status && robot.status !== f.status) return false;
    if (f.capability && !(robot.capabilities || []).includes(f.capability)) return false;
    return true;
  }

  filterOne(entry) {
    // The coalition at work stays in sight whatever the filters.
    const kept = Boolean(this.selection && this.selection.active && this.selection.robots.has(entry.robot.id));
    entry.group.classList.toggle("filtered", !kept && !this.matches(entry.robot));
  }

  // --- the fire ----------------------------------------------------------------
  setFire(point, announce = false) {
    this.fire = point;
    this.drawFire();
    if (announce && point) {
      document.getElementById("map-status").textContent = `Fire placed at x ${point[0]}, y ${point[1]}.`;
    }
  }

  drawFire() {
    const layer = this.layers.fire;
    layer.replaceChildren();
    if (!this.fire || !this.inForest(this.fire)) return;
    const [sx, sy] = this.toScreen(this.fire);
    const label = `fire ${fmtNumber(this.fire[0])}, ${fmtNumber(this.fire[1])}`;
    const right = sx < AREA.right - 250;  // room for the label at a phone's larger font
    layer.append(svg("g", { class: "fire-marker", id: "fire-marker", transform: `translate(${sx.toFixed(1)} ${sy.toFixed(1)})`,
      "data-x": this.fire[0], "data-y": this.fire[1] },
    svg("circle", { class: "fire-halo", r: 36 }),
    svg("use", { href: "#fire-icon", x: -24, y: -26, width: 48, height: 48 }),
    svg("text", { class: "fire-label", x: right ? 42 : -42, y: sy > AREA.bottom - 40 ? -30 : 8, "text-anchor": right ? "start" : "end", text: label })));
  }

  // --- pointer, wheel and keys ------------------------------------------------
  viewBoxPoint(event) {
    const matrix = this.svg.getScreenCTM();
    if (!matrix) return null;
    return new DOMPoint(event.clientX, event.clientY).matrixTransform(matrix.inverse());
  }

  pointerDown(event) {
    if (event.button !== undefined && event.button !== 0) return;
    this.pointers.set(event.pointerId, { x: event.clientX, y: event.clientY });
    if (this.pointers.size === 1) {
      this.gesture = { kind: "press", x: event.clientX, y: event.clientY, last: { x: event.clientX, y: event.clientY }, moved: false, target: event.target };
    } else if (this.pointers.size === 2) {
      const [a, b] = [...this.pointers.values()];
      this.gesture = { kind: "pinch", dist: Math.hypot(a.x - b.x, a.y - b.y), k: this.view.k, moved: true };
    }
  }

  pointerMove(event) {
    if (!this.pointers.has(event.pointerId)) return;
    this.pointers.set(event.pointerId, { x: event.clientX, y: event.clientY });
    const g = this.gesture;
    if (!g) return;
    if (g.kind === "pinch" && this.pointers.size === 2) {
      const [a, b] = [...this.pointers.values()];
      const dist = Math.hypot(a.x - b.x, a.y - b.y);
      const mid = this.viewBoxPoint({ clientX: (a.x + b.x) / 2, clientY: (a.y + b.y) / 2 });
      if (mid && g.dist > 0) this.zoomAt(mid.x, mid.y, (g.k * dist / g.dist) / this.view.k);
      return;
    }
    if (g.kind !== "press") return;
    if (!g.moved && Math.hypot(event.clientX - g.x, event.clientY - g.y) < DRAG_PX) return;
    if (!g.moved) {
      g.moved = true;
      this.svg.setPointerCapture?.(event.pointerId);
      this.svg.classList.add("panning");
    }
    const scale = this.svg.getScreenCTM()?.a || 1;
    this.panBy((event.clientX - g.last.x) / scale, (event.clientY - g.last.y) / scale);
    g.last = { x: event.clientX, y: event.clientY };
  }

  pointerUp(event) {
    const g = this.gesture;
    this.pointers.delete(event.pointerId);
    this.svg.classList.remove("panning");
    if (this.pointers.size === 0) this.gesture = null;
    if (!g || g.moved || g.kind !== "press") return;
    this.click(event, g.target);
  }

  setMode(mode) {
    this.mode = ["inspect", "end"].includes(mode) ? mode : "fire";
    this.svg.classList.toggle("inspect", this.mode === "inspect");
  }

  click(event, target) {
    const point = this.viewBoxPoint(event);
    if (!point) return;
    if (this.mode === "inspect" || event.shiftKey) {
      const group = target && target.closest && target.closest(".robot");
      const id = group ? group.dataset.robot : this.nearestRobot(point);
      this.onRobot(id || null);
      return;
    }
    if (point.x < AREA.left || point.x > AREA.right || point.y < AREA.top || point.y > AREA.bottom) return;
    const [x, y] = this.toWorld(point.x, point.y);
    const world = [Math.round(x), Math.round(y)];
    if (this.mode === "end") { this.onEnd(world); return; }
    this.setFire(world, true);
    this.onPlace(world);
  }

  // The shown robot nearest to a viewBox point, if one is within PICK_RADIUS.
  nearestRobot(point) {
    let best = null;
    let bestDistance = PICK_RADIUS;
    for (const [id, entry] of this.robots) {
      if (entry.group.classList.contains("filtered")) continue;
      const [sx, sy] = this.toScreen([entry.robot.x, entry.robot.y]);
      const distance = Math.hypot(sx - point.x, sy - point.y);
      if (distance <= bestDistance) { best = id; bestDistance = distance; }
    }
    return best;
  }

  wheel(event) {
    event.preventDefault();
    const point = this.viewBoxPoint(event);
    if (!point) return;
    const factor = Math.exp(-Math.max(-300, Math.min(300, event.deltaY)) * 0.002);
    this.zoomAt(point.x, point.y, factor);
  }

  key(event) {
    const arrows = { ArrowLeft: [-1, 0], ArrowRight: [1, 0], ArrowUp: [0, 1], ArrowDown: [0, -1] };
    if (event.key === "+" || event.key === "=") { event.preventDefault(); this.zoomBy(1.5); return; }
    if (event.key === "-" || event.key === "_") { event.preventDefault(); this.zoomBy(1 / 1.5); return; }
    if (event.key === "0") { event.preventDefault(); this.reset(); return; }
    if (event.key === "Escape") { this.onRobot(null); return; }
    if (event.key in arrows && event.altKey) {
      event.preventDefault();
      const [dx, dy] = arrows[event.key];
      this.panBy(-dx * SIDE * 0.1, dy * SIDE * 0.1);
      return;
    }
    const f = this.forest;
    const centre = [Math.round((f.x0 + f.x1) / 2), Math.round((f.y0 + f.y1) / 2)];
    let next = null;
    if (event.key in arrows) {
      const step = event.shiftKey ? 100 : 25;
      const [dx, dy] = arrows[event.key];
      next = this.fire
        ? [clamp(this.fire[0] + dx * step, f.x0, f.x1), clamp(this.fire[1] + dy * step, f.y0, f.y1)]
        : centre;
    } else if ((event.key === "Enter" || event.key === " ") && !this.fire) {
      next = centre;
    }
    if (!next) return;
    event.preventDefault();
    this.setFire(next, true);
    this.onPlace(next);
  }

  // Where a robot is on the page, for its details card.
  clientPoint(id) {
    const entry = this.robots.get(id);
    const matrix = this.svg.getScreenCTM();
    if (!entry || !matrix) return null;
    const [sx, sy] = this.toScreen([entry.robot.x, entry.robot.y]);
    return new DOMPoint(sx, sy).matrixTransform(matrix);
  }

  // --- the selected request ----------------------------------------------
  select(request) {
    if (!request) {
      this.selection = null;
    } else {
      const robots = new Set((request.coalition || request.robots || []).map((a) => (Array.isArray(a) ? a[0] : a.robot)));
      const active = !["rejected", "canceled", "failed", "completed"].includes(request.state);
      const location = request.task ? request.task.location : request.location;
      this.selection = { id: request.id, location, robots, active };
    }
    for (const entry of this.robots.values()) this.filterOne(entry);
    this.drawSelection();
  }

  drawSelection() {
    const { links, target, coalition, robots } = this.layers;
    links.replaceChildren();
    target.replaceChildren();
    const selection = this.selection;
    for (const [id, entry] of this.robots) {
      const inCoalition = Boolean(selection && selection.robots.has(id));
      if (inCoalition && !entry.halo) {
        entry.halo = [svg("circle", { class: "halo-glow", r: 27 }), svg("circle", { class: "halo", r: 21 })];
        entry.group.prepend(...entry.halo);
        coalition.append(entry.group);
      } else if (!inCoalition && entry.halo) {
        for (const node of entry.halo) node.remove();
        entry.halo = null;
        robots.append(entry.group);
      }
      entry.group.classList.toggle("in-coalition", inCoalition);
      entry.group.classList.toggle("dim", Boolean(selection && selection.robots.size && selection.active && !inCoalition));
    }
    if (!selection || !Array.isArray(selection.location)) return;
    const [tx, ty] = this.toScreen(selection.location);
    target.append(svg("circle", { class: "target", cx: tx, cy: ty, r: 44 }));
    if (!selection.active) return;
    for (const id of selection.robots) {
      const entry = this.robots.get(id);
      if (!entry) continue;
      const [sx, sy] = this.toScreen([entry.robot.x, entry.robot.y]);
      links.append(svg("line", { class: "link", x1: sx, y1: sy, x2: tx, y2: ty, "data-robot": id }));
    }
  }
}

function clamp(value, lo, hi) {
  return Math.min(hi, Math.max(lo, value));
}
