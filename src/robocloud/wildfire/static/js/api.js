// The wildfire server's narrow API. Calls never throw: each gives
// {ok, status, data, detail}, with detail the sentence to show on failure.

async function call(method, path, body, headers = {}) {
  let response;
  try {
    response = await fetch(path, {
      method,
      headers: body === undefined ? headers : { "Content-Type": "application/json", ...headers },
      body: body === undefined ? undefined : JSON.stringify(body),
      cache: "no-store",
    });
  } catch {
    return { ok: false, status: 0, data: null, detail: "the wildfire server cannot be reached." };
  }
  let data = null;
  try {
    data = await response.json();
  } catch {
    data = null;
  }
  if (response.ok) return { ok: true, status: response.status, data, detail: null };
  const detail = data && typeof data.detail === "string"
    ? data.detail : `the server answered ${response.status}.`;
  return { ok: false, status: response.status, data, detail };
}

export const api = {
  health: () => call("GET", "/api/health"),
  robots: () => call("GET", "/api/robots"),
  capabilities: () => call("GET", "/api/capabilities"),
  requests: (limit = 50) => call("GET", `/api/requests?limit=${limit}`),
  request: (id) => call("GET", `/api/requests/${encodeURIComponent(id)}`),
  send: (task, key) => call("POST", "/api/requests", task, key ? { "Idempotency-Key": key } : {}),
  cancel: (id) => call("POST", `/api/requests/${encodeURIComponent(id)}/cancel`),
};
