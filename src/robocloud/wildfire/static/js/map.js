// The forest map: robots coloured by cloud and shaped by state, the fire the
// operator places, and the selected request's coalition. Inline SVG, y up.

import { cloudColour, fmtNumber, svg, ticks } from "./util.js";

const AREA = { left: 84, top: 14, right: 958, bottom: 888 };  // viewBox 0 0 990 930
const GRID_STEP = 250;           // metres; the bounds grow in these steps
const FOREST = { x0: 0, y0: 0, x1: 2000, y1: 2000 };  // the simulator's forest
const STATUSES = ["idle", "reserved", "busy", "charging", "offline"];

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
  constructor(element, { onPlace }) {
    this.svg = element;
    this.onPlace = onPlace;
    this.bounds = { ...FOREST };
    this.robots = new Map();      // id -> {group, shape, title, status, position}
    this.fire = null;             // [x, y] or null
    this.selection = null;        // {location, robots: Set}
    this.layers = {};
    // The robots above the fire, so one working there stays visible.
    for (const name of ["ground", "grid", "target", "fire", "links", "robots"]) {
      this.layers[name] = svg("g", { class: name });
      this.svg.append(this.layers[name]);
    }
    this.drawGround();
    this.svg.addEventListener("click", (event) => this.click(event));
    this.svg.addEventListener("keydown", (event) => this.key(event));
  }

  // --- coordinates -------------------------------------------------------
  toScreen([x, y]) {
    const b = this.bounds;
    const w = AREA.right - AREA.left;
    const h = AREA.bottom - AREA.top;
    return [AREA.left + ((x - b.x0) / (b.x1 - b.x0)) * w, AREA.top + ((b.y1 - y) / (b.y1 - b.y0)) * h];
  }

  toWorld(sx, sy) {
    const b = this.bounds;
    const w = AREA.right - AREA.left;
    const h = AREA.bottom - AREA.top;
    const x = b.x0 + ((sx - AREA.left) / w) * (b.x1 - b.x0);
    const y = b.y1 - ((sy - AREA.top) / h) * (b.y1 - b.y0);
    return [Math.round(clamp(x, b.x0, b.x1)), Math.round(clamp(y, b.y0, b.y1))];
  }

  inside([x, y]) {
    const b = this.bounds;
    return x >= b.x0 && x <= b.x1 && y >= b.y0 && y <= b.y1;
  }

  // The forest grows (never shrinks) to hold every robot.
  fit(points) {
    const b = this.bounds;
    let grown = false;
    for (const [x, y] of points) {
      if (!Number.isFinite(x) || !Number.isFinite(y)) continue;
      if (x < b.x0) { b.x0 = Math.floor(x / GRID_STEP) * GRID_STEP; grown = true; }
      if (y < b.y0) { b.y0 = Math.floor(y / GRID_STEP) * GRID_STEP; grown = true; }
      if (x > b.x1) { b.x1 = Math.ceil(x / GRID_STEP) * GRID_STEP; grown = true; }
      if (y > b.y1) { b.y1 = Math.ceil(y / GRID_STEP) * GRID_STEP; grown = true; }
    }
    if (grown) {
      // Keep the forest square so metres are the same both ways.
      const side = Math.max(b.x1 - b.x0, b.y1 - b.y0);
      b.x1 = b.x0 + side;
      b.y1 = b.y0 + side;
      this.drawGround();
      for (const robot of this.robots.values()) this.move(robot, robot.position);
      this.drawFire();
      this.drawSelection();
    }
  }

  drawGround() {
    const { ground, grid } = this.layers;
    ground.replaceChildren(
      svg("rect", { class: "ground", x: AREA.left, y: AREA.top, width: AREA.right - AREA.left,
        height: AREA.bottom - AREA.top, rx: 6 }),
      this.trees(),
    );
    grid.replaceChildren();
    const b = this.bounds;
    const step = niceStep(b.x1 - b.x0);
    for (const x of ticks(b.x0, b.x1, (b.x1 - b.x0) / step)) {
      const [sx] = this.toScreen([x, b.y0]);
      grid.append(svg("line", { x1: sx, x2: sx, y1: AREA.top, y2: AREA.bottom }));
      if (labelled(x, step)) grid.append(svg("text", { x: sx, y: AREA.bottom + 30, "text-anchor": "middle", text: String(x) }));
    }
    for (const y of ticks(b.y0, b.y1, (b.y1 - b.y0) / step)) {
      const [, sy] = this.toScreen([b.x0, y]);
      grid.append(svg("line", { x1: AREA.left, x2: AREA.right, y1: sy, y2: sy }));
      if (labelled(y, step)) grid.append(svg("text", { x: AREA.left - 8, y: sy + 8, "text-anchor": "end", text: String(y) }));
    }
    grid.append(svg("rect", { class: "frame", x: AREA.left, y: AREA.top, width: AREA.right - AREA.left,
      height: AREA.bottom - AREA.top, rx: 6 }));
  }

  // Decorative canopy, the same on every page (a fixed pseudo-random sequence).
  trees() {
    const group = svg("g", { class: "trees", "aria-hidden": "true" });
    let seed = 7;
    const rand = () => { seed = (seed * 16807) % 2147483647; return seed / 2147483647; };
    for (let i = 0; i < 170; i++) {
      const x = AREA.left + 12 + rand() * (AREA.right - AREA.left - 24);
      const y = AREA.top + 12 + rand() * (AREA.bottom - AREA.top - 24);
      group.append(svg("circle", { cx: x.toFixed(1), cy: y.toFixed(1), r: (6 + rand() * 12).toFixed(1) }));
    }
    return group;
  }

  gridStep() {
    return niceStep(this.bounds.x1 - this.bounds.x0);
  }

  // --- robots ------------------------------------------------------------
  update(robots) {
    this.fit(robots.map((r) => r.position));
    const seen = new Set();
    for (const robot of robots) {
      seen.add(robot.id);
      let entry = this.robots.get(robot.id);
      if (!entry) {
        const group = svg("g", { class: "robot", "data-robot": robot.id });
        const title = svg("title");
        group.append(title);
        entry = { group, shape: null, title, status: null, position: robot.position, halo: null };
        this.robots.set(robot.id, entry);
        this.layers.robots.append(group);
      }
      const status = STATUSES.includes(robot.status) ? robot.status : "offline";
      if (status !== entry.status) {
        const shape = shapeFor(status);
        if (entry.shape) entry.shape.replaceWith(shape); else entry.group.append(shape);
        entry.shape = shape;
        entry.status = status;
        entry.group.setAttribute("class", `robot ${status}`);
        entry.group.setAttribute("data-status", status);
      }
      entry.shape.setAttribute("fill", cloudColour(robot.cloud));
      entry.shape.setAttribute("stroke", status === "offline" ? cloudColour(robot.cloud) : "#ffffff");
      entry.group.setAttribute("data-cloud", robot.cloud);
      entry.title.textContent = `${robot.id} · ${robot.cloud} · ${status} · battery ${fmtNumber(robot.battery)}%`
        + ` · ${(robot.capabilities || []).join(", ")}${robot.request ? ` · ${robot.request}` : ""}`;
      this.move(entry, robot.position);
    }
    for (const [id, entry] of this.robots) {
      if (!seen.has(id)) { entry.group.remove(); this.robots.delete(id); }
    }
    this.drawSelection();
  }

  move(entry, position) {
    entry.position = position;
    const [sx, sy] = this.toScreen(position);
    entry.group.style.transform = `translate(${sx.toFixed(1)}px, ${sy.toFixed(1)}px)`;
  }

  // --- the fire ----------------------------------------------------------
  // The forest grows for robots only: a mistyped x must not zoom the map out.
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
    if (!this.fire || !this.inside(this.fire)) return;
    const [sx, sy] = this.toScreen(this.fire);
    const label = `fire ${fmtNumber(this.fire[0])}, ${fmtNumber(this.fire[1])}`;
    const right = sx < AREA.right - 170;
    layer.append(svg("g", { class: "fire-marker", id: "fire-marker", transform: `translate(${sx.toFixed(1)} ${sy.toFixed(1)})`,
      "data-x": this.fire[0], "data-y": this.fire[1] },
    svg("circle", { class: "fire-halo", r: 36 }),
    svg("use", { href: "#fire-icon", x: -24, y: -26, width: 48, height: 48 }),
    svg("text", { class: "fire-label", x: right ? 42 : -42, y: 8, "text-anchor": right ? "start" : "end", text: label })));
  }

  click(event) {
    const matrix = this.svg.getScreenCTM();
    if (!matrix) return;
    const point = new DOMPoint(event.clientX, event.clientY).matrixTransform(matrix.inverse());
    if (point.x < AREA.left || point.x > AREA.right || point.y < AREA.top || point.y > AREA.bottom) return;
    const world = this.toWorld(point.x, point.y);
    this.setFire(world, true);
    this.onPlace(world);
  }

  key(event) {
    const moves = { ArrowLeft: [-1, 0], ArrowRight: [1, 0], ArrowUp: [0, 1], ArrowDown: [0, -1] };
    const b = this.bounds;
    const centre = [Math.round((b.x0 + b.x1) / 2), Math.round((b.y0 + b.y1) / 2)];
    let next = null;
    if (event.key in moves) {
      const step = event.shiftKey ? 100 : 25;
      const [dx, dy] = moves[event.key];
      const from = this.fire || centre;
      next = this.fire
        ? [clamp(from[0] + dx * step, b.x0, b.x1), clamp(from[1] + dy * step, b.y0, b.y1)]
        : centre;
    } else if ((event.key === "Enter" || event.key === " ") && !this.fire) {
      next = centre;
    }
    if (!next) return;
    event.preventDefault();
    this.setFire(next, true);
    this.onPlace(next);
  }

  // --- the selected request ----------------------------------------------
  select(request) {
    if (!request) {
      this.selection = null;
    } else {
      const robots = new Set((request.coalition || []).map((a) => a.robot));
      const active = !["rejected", "canceled", "failed"].includes(request.state);
      this.selection = { location: request.task?.location, robots, active };
    }
    this.drawSelection();
  }

  drawSelection() {
    const { links, target } = this.layers;
    links.replaceChildren();
    target.replaceChildren();
    const selection = this.selection;
    for (const [id, entry] of this.robots) {
      const inCoalition = Boolean(selection && selection.robots.has(id));
      if (inCoalition && !entry.halo) {
        entry.halo = [svg("circle", { class: "halo-glow", r: 27 }), svg("circle", { class: "halo", r: 21 })];
        entry.group.prepend(...entry.halo);
      } else if (!inCoalition && entry.halo) {
        for (const node of entry.halo) node.remove();
        entry.halo = null;
      }
      // Set every time: a change of state rewrites the robot's classes.
      entry.group.classList.toggle("in-coalition", inCoalition);
      entry.group.classList.toggle("dim", Boolean(selection && selection.robots.size && !inCoalition));
    }
    if (!selection || !Array.isArray(selection.location)) return;
    const [tx, ty] = this.toScreen(selection.location);
    target.append(svg("circle", { class: "target", cx: tx, cy: ty, r: 44 }));
    if (!selection.active) return;
    for (const id of selection.robots) {
      const entry = this.robots.get(id);
      if (!entry) continue;
      const [sx, sy] = this.toScreen(entry.position);
      links.append(svg("line", { class: "link", x1: sx, y1: sy, x2: tx, y2: ty }));
    }
  }
}

function clamp(value, lo, hi) {
  return Math.min(hi, Math.max(lo, value));
}

// Every other grid line carries its number, so labels stay readable.
function labelled(value, step) {
  return Math.round(value / step) % 2 === 0;
}

function niceStep(span) {
  if (span <= 2500) return 250;
  if (span <= 5000) return 500;
  return 10 ** Math.floor(Math.log10(span / 4));
}

