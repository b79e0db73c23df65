// Who is logged in (GET /api/auth/me) and what their role allows. Viewers see everything and may press
// the E-STOP; driving and releasing the e-stop need the operator role. With FLEET_AUTH=off the server
// reports an admin and the user chip is hidden.
import { CLIENT_ID, api, loginUrl } from "./api.js";
import { store } from "./store.js";

const RANK = { viewer: 1, operator: 2, admin: 3 };

let loaded;

export const session = {
  me: null, // {name, role, kind, username, auth}
  /** Resolves once /api/auth/me answered (or failed). */
  ready: new Promise((resolve) => (loaded = resolve)),

  /** True until /api/auth/me answered (the server enforces roles either way). */
  allows(role) {
    if (!this.me) return true;
    return (RANK[this.me.role] ?? 0) >= RANK[role];
  },

  /** Who this tab is as a control-lease holder (the server's ``Actor.lease_holder``). */
  holder() {
    return this.me?.auth ? this.me.subject : `client:${CLIENT_ID}`;
  },

  async load() {
    try {
      this.me = await api.me();
    } catch {
      this.me = null; // a 401 already sent the browser to the login page
    }
    loaded();
    store.emit("session", this.me);
    return this.me;
  },
};

export function setupUserChip() {
  const chip = document.getElementById("user");
  const name = document.getElementById("user-name");
  const logout = document.getElementById("logout");
  store.on("session", (me) => {
    chip.hidden = !me || !me.auth;
    if (!me) return;
    name.textContent = `${me.username ?? me.name} · ${me.role}`;
    name.title = `${me.name} (${me.kind})`;
  });
  logout.addEventListener("click", async () => {
    try {
      await api.logout();
    } finally {
      location.assign(loginUrl());
    }
  });
}
