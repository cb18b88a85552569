// The live state pushed by the wildfire server (GET /api/live, server-sent
// events): a snapshot, then a delta every tick with only what changed.
// EventSource reconnects by itself; each reconnection starts from a snapshot.

import { FINAL_STATES } from "./util.js";

// No event for this long: the page says what it shows is old (the server's
// config says how long; this until its first snapshot).
const SILENT_AFTER_S = 5;

export class Live {
  constructor({ onSnapshot, onDelta, onLink }) {
    this.onSnapshot = onSnapshot;
    this.onDelta = onDelta;
    this.onLink = onLink;
    this.columns = [];
    this.robots = new Map();      // id -> {id, cloud, status, x, y, battery, ...}
    this.clouds = [];
    this.endpoints = [];
    this.capabilities = [];
    this.config = null;
    this.alerts = [];
    this.requests = new Map();    // id -> summary
    this.offset = 0;              // server clock minus this page's, seconds
    this.lastEvent = 0;           // this page's clock, seconds
    this.link = "connecting";     // "live", "silent" or "down"
    this.linkSince = Date.now() / 1000;
    this.events = 0;
  }

  start() {
    this.source = new EventSource("/api/live");
    this.source.addEventListener("snapshot", (e) => this.snapshot(JSON.parse(e.data)));
    this.source.addEventListener("delta", (e) => this.delta(JSON.parse(e.data)));
    this.source.addEventListener("error", () => this.setLink("down"));
    // Looked at four times a second: the page says so within a quarter second of the limit.
    setInterval(() => {
      if (this.link === "live" && this.localNow() - this.lastEvent > this.silentAfter()) this.setLink("silent");
    }, 250);
  }

  silentAfter() { return (this.config && this.config.silent_after) || SILENT_AFTER_S; }

  // Seconds since the epoch on this page's clock, and on the server's.
  localNow() { return Date.now() / 1000; }
  now() { return this.localNow() + this.offset; }

  setLink(link) {
    if (link === this.link) return;
    this.link = link;
    this.linkSince = this.localNow();
    this.onLink(link);
  }

  heard(now) {
    this.events += 1;
    this.lastEvent = this.localNow();
    this.offset = now - this.lastEvent;
    this.setLink("live");
  }

  snapshot(data) {
    this.heard(data.now);
    this.columns = data.robots.columns;
    this.robots = new Map(data.robots.rows.map((row) => [row[0], this.robot(row)]));
    this.config = data.config;
    this.clouds = data.clouds;
    this.endpoints = data.endpoints;
    this.capabilities = data.capabilities;
    this.alerts = data.alerts;
    this.requests = new Map(data.requests.map((r) => [r.id, r]));
    this.onSnapshot(this);
  }

  robot(row) {
    const robot = {};
    this.columns.forEach((name, i) => { robot[name] = row[i]; });
    return robot;
  }

  delta(data) {
    this.heard(data.now);
    const changed = new Set();
    const added = [];
    const removed = [];
    if (data.robots) {
      for (const row of data.robots.add || []) {
        this.robots.set(row[0], this.robot(row));
        added.push(row[0]);
      }
      for (const change of data.robots.set || []) {
        const robot = this.robots.get(change[0]);
        if (!robot) continue;
        for (let i = 1; i < change.length; i += 2) robot[this.columns[change[i]]] = change[i + 1];
        changed.add(change[0]);
      }
      for (const id of data.robots.del || []) {
        this.robots.delete(id);
        removed.push(id);
      }
    }
    for (const name of ["config", "clouds", "endpoints", "capabilities"]) {
      if (data[name] !== undefined) this[name] = data[name];
    }
    const alerts = data.alerts || [];
    this.alerts.push(...alerts);
    if (this.alerts.length > 200) this.alerts.splice(0, this.alerts.length - 200);
    for (const summary of data.requests || []) this.requests.set(summary.id, summary);
    this.onDelta(this, { added, changed, removed, alerts, requests: data.requests || [], data });
  }

  timeScale() {
    const scale = this.config && this.config.time_scale;
    return Number.isFinite(scale) && scale > 0 ? scale : 1;
  }

  // A robot's stale age in seconds, or null when it is fresh.
  age(robot) {
    if (robot.heard === null || robot.heard === undefined) return null;
    return Math.max(0, this.now() - robot.heard);
  }

  // Real seconds until a robot of a coalition is done: what is left of its
  // time t_i (robot seconds), at the robots' time scale.
  robotEta(robot, time) {
    if (!robot || !Number.isFinite(time)) return null;
    if (robot.phase === "done") return 0;
    if (robot.phase !== "travel" && robot.phase !== "work") return null;
    const left = 1 - (Number.isFinite(robot.progress) ? robot.progress : 0);
    return Math.max(0, left * time) / this.timeScale();
  }

  // Robot id -> {request, time} for the coalitions of unfinished requests.
  assignments() {
    const map = new Map();
    for (const request of this.requests.values()) {
      if (FINAL_STATES.has(request.state)) continue;
      for (const [id, , time] of request.robots || []) map.set(id, { request, time });
    }
    return map;
  }

  // Real seconds until a request's coalition is done, or null. A robot is
  // in one active coalition at most, so its task phase is this request's.
  requestEta(summary) {
    if (!summary || !["dispatched", "underway"].includes(summary.state)) return null;
    let eta = null;
    for (const [id, , time] of summary.robots || []) {
      const value = this.robotEta(this.robots.get(id), time);
      if (value !== null) eta = Math.max(eta ?? 0, value);
    }
    if (eta === null && Number.isFinite(summary.time)) eta = summary.time / this.timeScale();
    return eta;
  }
}
