// The ROBOTS and REQUESTS tables: sort by a column (click its header), filter,
// page. Robots come from the live fleet, paged here; requests come from the
// wildfire server a page at a time (beyond the IaaS's 50) and are kept live
// by the pushed summaries.

import {
  cloudColour, el, epoch, FINAL_STATES, fmtAge, fmtClock, fmtDuration, fmtNumber, humanize, sentence,
} from "./util.js";

const ROBOTS_PER_PAGE = 50;
export const REQUESTS_PER_PAGE = 25;

// A table whose rows are drawn from plain objects: columns say how to show and sort.
class Table {
  constructor(table, columns, { onRow }) {
    this.table = table;
    this.columns = columns;
    this.onRow = onRow;
    this.sort = { key: columns[0].key, dir: 1 };
    const head = el("tr");
    for (const column of columns) {
      const button = el("button", { type: "button", class: "sort", "data-sort": column.key, text: column.title });
      button.addEventListener("click", () => this.sortBy(column.key));
      const th = el("th", { scope: "col", class: column.num ? "num" : null, "data-key": column.key }, button);
      column.th = th;
      head.append(th);
    }
    this.body = el("tbody");
    table.replaceChildren(el("thead", {}, head), this.body);
    this.markSort();
  }

  sortBy(key) {
    this.sort = { key, dir: this.sort.key === key ? -this.sort.dir : 1 };
    this.markSort();
    this.render();
  }

  markSort() {
    for (const column of this.columns) {
      const state = column.key === this.sort.key ? (this.sort.dir > 0 ? "ascending" : "descending") : "none";
      column.th.setAttribute("aria-sort", state);
    }
  }

  sorted(items) {
    const column = this.columns.find((c) => c.key === this.sort.key) || this.columns[0];
    const value = column.sortValue || ((item) => column.value(item));
    const keyed = items.map((item) => [value(item), item]);
    keyed.sort((a, b) => {
      const [x, y] = [a[0], b[0]];
      const missingX = x === null || x === undefined || Number.isNaN(x);
      const missingY = y === null || y === undefined || Number.isNaN(y);
      if (missingX || missingY) return missingX === missingY ? 0 : (missingX ? 1 : -1);  // blanks last
      return (x < y ? -1 : x > y ? 1 : 0) * this.sort.dir;
    });
    return keyed.map(([, item]) => item);
  }

  // Rows are kept by id and only their changed cells rewritten, so a row keeps
  // its focus and its hover while the table stays live.
  draw(items, idOf) {
    if (!this.rows) this.rows = new Map();
    const keep = new Set();
    const ordered = items.map((item) => {
      const id = idOf(item);
      keep.add(id);
      let row = this.rows.get(id);
      if (!row) {
        row = el("tr", { "data-id": id, tabindex: 0 });
        for (const column of this.columns) {
          row.append(el("td", { class: column.num ? "num" : null, "data-key": column.key, "data-label": column.title }));
        }
        row.addEventListener("click", () => this.onRow(id));
        row.addEventListener("keydown", (e) => { if (e.key === "Enter") this.onRow(id); });
        this.rows.set(id, row);
      }
      this.columns.forEach((column, i) => {
        const cell = row.children[i];
        const shown = column.cell ? column.cell(item) : column.value(item);
        if (shown instanceof Node) {
          const html = shown.outerHTML;
          if (cell.dataset.html !== html) { cell.replaceChildren(shown); cell.dataset.html = html; }
        } else {
          const text = shown === null || shown === undefined || shown === "" ? "–" : String(shown);
          if (cell.textContent !== text || cell.dataset.html) { cell.textContent = text; delete cell.dataset.html; }
        }
      });
      return row;
    });
    for (const id of [...this.rows.keys()]) if (!keep.has(id)) this.rows.delete(id);
    const current = [...this.body.children];
    if (current.length !== ordered.length || current.some((row, i) => row !== ordered[i])) {
      this.body.replaceChildren(...ordered);
    }
  }
}

function cloudCell(cloud) {
  const swatch = el("span", { class: "swatch", "aria-hidden": "true" });
  swatch.style.background = cloudColour(cloud);
  return el("span", { class: "cloud-cell" }, swatch, cloud);
}

export class RobotsTable extends Table {
  constructor(table, { live, onRow, summary, pager }) {
    // A robot's request as this application knows it: the one whose coalition holds it.
    let self = null;
    const assignment = (robot) => (self && self.assigned.get(robot.id)) || null;
    const eta = (robot) => {
      const a = assignment(robot);
      return a ? live.robotEta(robot, a.time) : null;
    };
    // Busy or reserved for none of this application's requests: someone else's work, said so.
    const request = (robot) => {
      const a = assignment(robot);
      if (a) return a.request.label ? `${a.request.label} (${a.request.id})` : a.request.id;
      if (robot.request) return `${robot.request} (not ours)`;
      return robot.status === "busy" || robot.status === "reserved" ? "outside this app" : null;
    };
    super(table, [
      { key: "id", title: "Robot", value: (r) => r.id },
      { key: "cloud", title: "Cloud", value: (r) => r.cloud, cell: (r) => cloudCell(r.cloud) },
      { key: "status", title: "Status", value: (r) => r.status,
        cell: (r) => el("span", { class: "status", "data-status": r.status, text: r.status }) },
      { key: "battery", title: "Battery", num: true, value: (r) => r.battery, cell: (r) => `${fmtNumber(r.battery)}%` },
      { key: "capabilities", title: "Capabilities", value: (r) => (r.capabilities || []).join(", ") },
      { key: "request", title: "Request", value: request },
      { key: "eta", title: "ETA", num: true, value: eta, cell: (r) => { const v = eta(r); return v === null ? "–" : fmtDuration(v); } },
      { key: "heard", title: "Last heard", num: true, value: (r) => live.age(r) ?? 0,
        cell: (r) => { const age = live.age(r); return age === null ? `within ${fmtNumber((live.config && live.config.stale_after) || 5)} s` : fmtAge(age); } },
    ], { onRow });
    self = this;
    this.assigned = new Map();
    this.live = live;
    this.summary = summary;
    this.pager = pager;
    this.page = 0;
    this.search = "";
    this.filter = () => true;
    this.visible = true;
  }

  setFilter(filter, search) {
    this.filter = filter;
    this.search = search.trim().toLowerCase();
    this.page = 0;
    this.render();
  }

  render() {
    if (!this.visible) return;
    this.assigned = this.live.assignments();
    const all = [...this.live.robots.values()];
    const shown = this.sorted(all.filter((r) => this.filter(r) && (!this.search || r.id.toLowerCase().includes(this.search))));
    const pages = Math.max(1, Math.ceil(shown.length / ROBOTS_PER_PAGE));
    this.page = Math.min(this.page, pages - 1);
    const start = this.page * ROBOTS_PER_PAGE;
    const rows = shown.slice(start, start + ROBOTS_PER_PAGE);
    this.draw(rows, (r) => r.id);
    for (const row of this.body.children) {
      const robot = this.live.robots.get(row.dataset.id);
      row.classList.toggle("stale", Boolean(robot && this.live.age(robot) !== null));
    }
    this.summary.textContent = shown.length
      ? `${fmtNumber(start + 1)}–${fmtNumber(start + rows.length)} of ${fmtNumber(shown.length)}`
        + (shown.length < all.length ? ` (filtered from ${fmtNumber(all.length)})` : "")
      : `none of ${fmtNumber(all.length)} robots match`;
    this.pager.previous.disabled = this.page === 0;
    this.pager.next.disabled = this.page >= pages - 1;
    this.pager.label.textContent = `page ${this.page + 1} of ${pages}`;
  }

  turn(step) {
    this.page = Math.max(0, this.page + step);
    this.render();
  }
}

export function elapsed(summary, now) {
  const start = epoch(summary.created_at);
  const end = FINAL_STATES.has(summary.state) ? epoch(summary.updated_at) : now;
  return Number.isFinite(start) && Number.isFinite(end) ? Math.max(0, end - start) : null;
}

export class RequestsTable extends Table {
  constructor(table, { live, onRow }) {
    super(table, [
      { key: "created", title: "Sent", value: (q) => epoch(q.created_at), cell: (q) => fmtClock(q.created_at) },
      { key: "state", title: "State", value: (q) => q.state,
        cell: (q) => el("span", { class: "badge", "data-state": q.state, text: q.state }) },
      { key: "label", title: "Request", value: (q) => (q.label || q.id).toLowerCase(),
        cell: (q) => el("span", { class: "what" }, el("span", { class: "title", text: q.label || q.id }),
          q.label ? el("span", { class: "meta", text: q.id }) : null) },
      { key: "robots", title: "Robots", num: true, value: (q) => (q.robots || []).length,
        cell: (q) => ((q.robots || []).length ? fmtNumber(q.robots.length) : "–") },
      { key: "elapsed", title: "Elapsed", num: true, value: (q) => elapsed(q, live.now()),
        cell: (q) => fmtDuration(elapsed(q, live.now())) },
      { key: "eta", title: "ETA", num: true, value: (q) => live.requestEta(q),
        cell: (q) => { const v = live.requestEta(q); return v === null ? (FINAL_STATES.has(q.state) ? "–" : "…") : fmtDuration(v); } },
      { key: "reason", title: "Outcome", value: (q) => q.reason || "",
        cell: (q) => el("span", { class: "reason-cell", title: sentence(humanize(q.reason)), text: q.reason ? sentence(humanize(q.reason)) : (FINAL_STATES.has(q.state) ? q.state : "") }) },
    ], { onRow });
    this.sort = { key: "created", dir: -1 };
    this.markSort();
    this.live = live;
    this.items = [];
    this.selectedId = null;
  }

  setItems(items) {
    this.items = items;
    this.render();
  }

  // A pushed summary: the row changes in place.
  update(summary) {
    const index = this.items.findIndex((q) => q.id === summary.id);
    if (index < 0) return false;
    this.items[index] = { ...this.items[index], ...summary, cloud: summary.cloud || this.items[index].cloud };
    return true;
  }

  render() {
    this.draw(this.sorted(this.items), (q) => q.id);
    for (const row of this.body.children) {
      row.setAttribute("aria-selected", String(row.dataset.id === this.selectedId));
      const item = this.items.find((q) => q.id === row.dataset.id);
      if (item) row.dataset.state = item.state;
    }
  }
}
