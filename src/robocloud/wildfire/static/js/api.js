// The wildfire server's narrow API. Calls never throw: each gives
// {ok, status, data, detail, delivery}, with detail the sentence to show on
// failure and delivery, for a failure, whether the call may have been acted
// on all the same ("unknown") or surely was not ("none").

const TIMEOUT_MS = 20000;  // beyond the server's own wait for an IaaS

async function call(method, path, body, headers = {}) {
  const abort = new AbortController();
  const timer = setTimeout(() => abort.abort(), TIMEOUT_MS);
  let response;
  try {
    response = await fetch(path, {
      method,
      headers: body === undefined ? headers : { "Content-Type": "application/json", ...headers },
      body: body === undefined ? undefined : JSON.stringify(body),
      cache: "no-store",
      signal: abort.signal,
    });
  } catch {
    // The call may have left before the connection broke: nothing says it did not arrive.
    return { ok: false, status: 0, data: null, delivery: "unknown",
      detail: abort.signal.aborted ? "the wildfire server did not answer in time"
        : "the wildfire server cannot be reached" };
  } finally {
    clearTimeout(timer);
  }
  let data = null;
  try {
    data = await response.json();
  } catch {
    data = null;
  }
  if (response.ok) return { ok: true, status: response.status, data, detail: null, delivery: "done" };
  const detail = data && typeof data.detail === "string" ? data.detail : `the server answered ${response.status}`;
  const delivery = data && data.delivery ? data.delivery : (response.status >= 500 ? "unknown" : "refused");
  return { ok: false, status: response.status, data, detail, delivery };
}

export const api = {
  requests: ({ state = "", limit = 25, before = "" } = {}) => {
    const query = new URLSearchParams({ limit: String(limit) });
    if (state) query.set("state", state);
    if (before) query.set("before", before);
    return call("GET", `/api/requests?${query}`);
  },
  request: (id) => call("GET", `/api/requests/${encodeURIComponent(id)}`),
  send: (task, key) => call("POST", "/api/requests", task, { "Idempotency-Key": key }),
  cancel: (id) => call("POST", `/api/requests/${encodeURIComponent(id)}/cancel`),
  // Missions: several fires planned as one (mission.js, missionview.js).
  missions: ({ limit = 20 } = {}) => call("GET", `/api/missions?${new URLSearchParams({ limit: String(limit) })}`),
  mission: (id) => call("GET", `/api/missions/${encodeURIComponent(id)}`),
  sendMission: (mission, key) => call("POST", "/api/missions", mission, { "Idempotency-Key": key }),
  cancelMission: (id) => call("DELETE", `/api/missions/${encodeURIComponent(id)}`),
  missionEvents: (id) => `/api/missions/${encodeURIComponent(id)}/events`,
};
