// REST helpers. Every call goes to the same origin; errors carry the server's message.

export class ApiError extends Error {
  constructor(status, message, code = null) {
    super(message);
    this.status = status;
    this.code = code; // the server's machine-readable code (backend/core/errors.py)
  }
}

// This tab's own id: with authentication off it is the control-lease holder, so two tabs never both drive
// one robot (with authentication on the logged-in user is).
export const CLIENT_ID = (() => {
  let id = sessionStorage.getItem("fleet-client-id");
  if (!id) {
    id = `tab-${Math.random().toString(36).slice(2, 10)}`;
    sessionStorage.setItem("fleet-client-id", id);
  }
  return id;
})();

async function request(method, path, body) {
  const init = { method, headers: { "X-Fleet-Client": CLIENT_ID }, credentials: "same-origin" };
  if (body !== undefined) {
    init.headers["Content-Type"] = "application/json";
    init.body = JSON.stringify(body);
  }
  const res = await fetch(path, init);
  if (res.status === 401 && !location.pathname.startsWith("/login")) {
    location.assign(loginUrl());
    throw new ApiError(401, "login required");
  }
  const text = await res.text();
  let data = null;
  try {
    data = text ? JSON.parse(text) : null;
  } catch {
    data = text;
  }
  if (!res.ok && res.status !== 504) {
    const detail = data && typeof data === "object" && "detail" in data ? data.detail : text;
    throw new ApiError(res.status, describe(detail), data && typeof data === "object" ? data.code ?? null : null);
  }
  return data;
}

/** A FastAPI error detail as a sentence: validation errors as "field: message; ...". */
function describe(detail) {
  if (typeof detail === "string") return detail;
  if (Array.isArray(detail) && detail.every((e) => e && typeof e.msg === "string")) {
    return detail.map((e) => {
      const field = (e.loc ?? []).filter((p) => p !== "body" && p !== "query" && p !== "path").join(".");
      return field ? `${field}: ${e.msg}` : e.msg;
    }).join("; ");
  }
  return JSON.stringify(detail);
}

export const api = {
  get: (path) => request("GET", path),
  del: (path) => request("DELETE", path),
  post: (path, body) => request("POST", path, body ?? {}),
  patch: (path, body) => request("PATCH", path, body ?? {}),
  put: (path, body) => request("PUT", path, body ?? {}),
  del: (path) => request("DELETE", path),
  robots: () => request("GET", "/api/robots"),
  command: (robotId, command, args = {}, opts = {}) =>
    request("POST", `/api/robots/${encodeURIComponent(robotId)}/commands`, {
      command,
      args,
      ttl_s: opts.ttl_s ?? 1.0,
      source: opts.source ?? "ui",
    }),
  estop: (reason) => request("POST", "/api/estop", { reason: reason ?? "dashboard", source: "ui" }),
  release: () => request("POST", "/api/estop/release", { source: "ui" }),
  estopState: () => request("GET", "/api/estop"),
  hold: (robotId, reason) => request("PUT", `/api/robots/${encodeURIComponent(robotId)}/hold`, { reason: reason ?? "" }),
  takeControl: (robotId, force = false) =>
    request("POST", `/api/robots/${encodeURIComponent(robotId)}/lease${force ? "?force=true" : ""}`),
  releaseControl: (robotId) => request("DELETE", `/api/robots/${encodeURIComponent(robotId)}/lease`),
  requestControl: (robotId) => request("POST", `/api/robots/${encodeURIComponent(robotId)}/lease/request`),
  grantControl: (robotId, toHolder, toName) =>
    request("POST", `/api/robots/${encodeURIComponent(robotId)}/lease/grant`, { to_holder: toHolder, to_name: toName }),
  releaseHold: (robotId) => request("DELETE", `/api/robots/${encodeURIComponent(robotId)}/hold`),
  telemetry: (robotId, params) =>
    request("GET", `/api/robots/${encodeURIComponent(robotId)}/telemetry?${new URLSearchParams(params)}`),
  streams: (robotId) => request("GET", `/api/robots/${encodeURIComponent(robotId)}/streams`),
  commands: (robotId) => request("GET", `/api/robots/${encodeURIComponent(robotId)}/commands`),
  me: () => request("GET", "/api/auth/me"),
  logout: () => request("POST", "/api/auth/logout"),
};

/** The login page's URL, coming back to where the user is now. */
export function loginUrl() {
  return `/login?next=${encodeURIComponent(location.pathname + location.search)}`;
}
