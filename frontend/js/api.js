// REST helpers. Every call goes to the same origin; errors carry the server's message.

export class ApiError extends Error {
  constructor(status, message) {
    super(message);
    this.status = status;
  }
}

async function request(method, path, body) {
  const init = { method, headers: {}, credentials: "same-origin" };
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
    throw new ApiError(res.status, typeof detail === "string" ? detail : JSON.stringify(detail));
  }
  return data;
}

export const api = {
  get: (path) => request("GET", path),
  post: (path, body) => request("POST", path, body ?? {}),
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
