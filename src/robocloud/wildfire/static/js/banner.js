// The banner says what holds NOW, not what happened once. Each condition is
// worked out again from the live state (every second and on every delta) and
// goes away when it no longer holds:
//
//   the wildfire server silent or lost   while the link is not live
//   no IaaS answers                      while none answers
//   a cloud down                         while its status is down
//   a robot of a request failed          until it is replaced, or the request ends
//   a robot replaced by another          while the request runs: says whether it is
//                                        still within its max time, and its ETA
//   news (a cloud back, a request        for NEWS_S seconds
//   rejected or failed, ...)
//
// The most serious shows; the others are counted ("and 2 more: see Alerts").
// Dismiss hides the one shown until its words change.

import { FINAL_STATES, fmtClock, fmtDuration, fmtNumber } from "./util.js";

const NEWS_S = 15;
const RANK = { danger: 0, warning: 1, info: 2, ok: 3 };
// "robot c-0307 failed: it has been silent for 5 s" / "robot c-0307 replaced by c-0123, c-0042"
const ROBOT_EVENT = /robot (\S+) (failed|replaced by)(?::? ?)(.*?)\.?(?= The coalition|$)/;

export class Banner {
  constructor(live) {
    this.live = live;
    this.robotEvents = new Map();   // request id -> {robot, kind, detail, at}
    this.failures = new Map();      // request id -> why its robot failed (kept for the replacement's words)
    this.news = [];                 // {key, level, text, at}
    this.dismissed = new Set();     // keys of conditions the operator dismissed
  }

  // Alerts as they arrive (from the server, or the page's own about its link).
  take(alerts) {
    for (const alert of alerts) {
      const match = alert.kind === "robot" && alert.request ? ROBOT_EVENT.exec(alert.text) : null;
      if (match) {
        const [, robot, what, rest] = match;
        const kind = what === "failed" ? "failed" : "replaced";
        if (kind === "failed") this.failures.set(alert.request, { robot, why: rest });
        this.robotEvents.set(alert.request, { robot, kind, detail: rest, at: alert.at, id: alert.id });
        continue;
      }
      if (alert.kind === "cloud" && alert.level === "danger") continue;  // a condition: from the cloud's status
      if (alert.kind === "server" && alert.level === "danger") continue;  // a condition: from the link
      if (alert.kind === "iaas" && alert.level !== "ok") continue;        // a condition: from the endpoints
      if (this.news.some((n) => n.key === `news:${alert.id}`)) continue;
      this.news.push({ key: `news:${alert.id}`, level: alert.level, text: alert.text, at: alert.at });
    }
    if (this.news.length > 20) this.news.splice(0, this.news.length - 20);
  }

  // Every condition that holds now, the most serious first.
  conditions() {
    const live = this.live;
    const out = [];
    if (live.link === "down" || live.link === "silent") {
      out.push({ key: `link:${live.link}`, level: "danger",
        text: live.link === "down"
          ? "The wildfire server cannot be reached: the page shows the fleet and the requests as last heard, greyed."
          : `The wildfire server has sent nothing for ${fmtNumber(live.silentAfter())} s: the page shows what it last heard, greyed.` });
    }
    if (live.endpoints.length && !live.endpoints.some((e) => e.ok)) {
      out.push({ key: "iaas:none", level: "danger",
        text: "No IaaS answers: the page shows the fleet and the requests as last heard." });
    }
    for (const cloud of live.clouds) {
      if (cloud.status !== "down") continue;
      const said = [...live.alerts].reverse().find((a) => a.kind === "cloud" && a.cloud === cloud.name && a.level === "danger");
      const text = said ? said.text : `${cloud.name} is down: ${cloud.reason || "it does not answer"}.`;
      out.push({ key: `cloud:${cloud.name}:${cloud.since}`, level: "danger",
        text: `${text} (down for ${fmtDuration(live.now() - cloud.since)})` });
    }
    for (const [id, event] of this.robotEvents) {
      const summary = live.requests.get(id);
      if (!summary || FINAL_STATES.has(summary.state)) continue;
      const name = summary.label ? `Request “${summary.label}” (${id})` : `Request ${id}`;
      if (event.kind === "failed") {
        out.push({ key: `robot:${id}:${event.id}`, level: "warning",
          text: `${name}: robot ${event.robot} failed${event.detail ? ` (${event.detail})` : ""}; its IaaS is looking for a replacement.` });
      } else {
        const failed = this.failures.get(id);
        const what = failed && failed.robot === event.robot
          ? `robot ${event.robot} failed${failed.why ? ` (${failed.why})` : ""} and was replaced by ${event.detail}`
          : `robot ${event.robot} was replaced by ${event.detail}`;
        out.push({ key: `robot:${id}:${event.id}`, level: "info", text: `${name}: ${what}; ${this.onTime(summary)}` });
      }
    }
    const now = live.now();
    for (const item of this.news) {
      if (Math.abs(now - item.at) < NEWS_S) out.push(item);  // (alerts carry the server's clock)
    }
    out.sort((a, b) => RANK[a.level] - RANK[b.level]);
    return out.filter((c) => !this.dismissed.has(c.key));
  }

  // Whether a request is still on time, from its own numbers: its coalition's
  // time against its max time (robot time), and its ETA (real time).
  onTime(summary) {
    const parts = [];
    if (Number.isFinite(summary.time) && Number.isFinite(summary.max_time)) {
      parts.push(summary.time <= summary.max_time
        ? `the request is still on time (${fmtDuration(summary.time)} of its ${fmtDuration(summary.max_time)} robot time)`
        : `the request is now late (${fmtDuration(summary.time)}, over its ${fmtDuration(summary.max_time)} robot time)`);
    } else {
      parts.push("the request goes on");
    }
    const eta = this.live.requestEta(summary);
    if (eta !== null) parts.push(`ETA ≈ ${fmtDuration(eta)}`);
    return `${parts.join(", ")}.`;
  }

  // The banner's element: the most serious condition, and how many more.
  draw(element, textElement) {
    const all = this.conditions();
    const first = all[0];
    element.hidden = !first;
    if (!first) {
      delete element.dataset.key;
      textElement.textContent = "";  // nothing holds: no old words left behind, even hidden
      return null;
    }
    element.dataset.level = first.level;
    element.dataset.key = first.key;
    const more = all.length - 1;
    const when = first.at ? `${fmtClock(first.at)} · ` : "";
    const text = `${when}${first.text}${more ? ` (and ${more} more: see Alerts)` : ""}`;
    if (textElement.textContent !== text) textElement.textContent = text;
    return first;
  }

  dismiss(key) {
    if (key) this.dismissed.add(key);
  }
}
