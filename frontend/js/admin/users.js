// Users & tokens (admins): create users, change their role, disable or enable them, reset a password (a new
// random one, shown once); create API tokens (the secret is shown once) and revoke them. Everything goes
// through the REST API (/api/users, /api/tokens), which checks the role, validates and audits; its error
// messages are shown inline next to the form or row they concern.
import { announce } from "../core/a11y.js";
import { api } from "../core/api.js";
import { session } from "../core/session.js";
import { el } from "../core/util.js";

const ROLES = ["viewer", "operator", "admin"];
// a token may also be "metrics": GET /metrics only (a Prometheus scrape), nothing else
const TOKEN_ROLES = ["metrics", ...ROLES];
const CONFIRM_MS = 4000;

function newPassword() {
  const bytes = crypto.getRandomValues(new Uint8Array(12));
  return btoa(String.fromCharCode(...bytes)).replace(/\+/g, "-").replace(/\//g, "_");
}

function when(ts) {
  return ts == null ? "—" : new Date(ts * 1000).toLocaleString([], { hour12: false });
}

function roleSelect(value, label, attrs = {}, roles = ROLES) {
  return el("select", { "aria-label": label, ...attrs }, ...roles.map((r) => el("option", { value: r, selected: r === value }, r)));
}

/** A button that needs a second press within CONFIRM_MS (revoking, disabling). */
function confirmButton(label, confirmLabel, attrs, action) {
  let timer = null;
  const b = el("button", { type: "button", class: "btn small", ...attrs }, label);
  b.addEventListener("click", () => {
    if (!timer) {
      b.textContent = confirmLabel;
      b.classList.add("confirm");
      timer = setTimeout(() => {
        timer = null;
        b.textContent = label;
        b.classList.remove("confirm");
      }, CONFIRM_MS);
      return;
    }
    clearTimeout(timer);
    timer = null;
    action();
  });
  return b;
}

export class UsersView {
  constructor(host) {
    this.host = host;
    this.status = el("p", { class: "form-ok", role: "status", "data-testid": "users-status" });
    this.error = el("p", { class: "form-error", "data-testid": "users-error" });
    this.secret = el("div", { "data-testid": "shown-once", hidden: true });
    this.userRows = el("tbody", { "data-testid": "user-rows" });
    this.tokenRows = el("tbody", { "data-testid": "token-rows" });
    this.userForm = this.buildUserForm();
    this.tokenForm = this.buildTokenForm();
    this.denied = el("p", { class: "inline-note", "data-testid": "users-denied", hidden: true });
    host.replaceChildren(this.denied, this.status, this.error, this.secret,
      el("div", { class: "users-grid" },
        el("section", { class: "panel", "aria-labelledby": "users-h" }, el("h2", { id: "users-h", class: "panel-title" }, "Users"),
          this.userForm.form, this.userForm.error,
          el("table", { class: "plain", "data-testid": "users-table" },
            el("thead", {}, el("tr", {}, el("th", {}, "User"), el("th", {}, "Role"), el("th", {}, "State"), el("th", {}, "Actions"))),
            this.userRows)),
        el("section", { class: "panel", "aria-labelledby": "tokens-h" }, el("h2", { id: "tokens-h", class: "panel-title" }, "API tokens"),
          this.tokenForm.form, this.tokenForm.error,
          el("table", { class: "plain", "data-testid": "tokens-table" },
            el("thead", {}, el("tr", {}, el("th", {}, "Name"), el("th", {}, "Role"), el("th", {}, "Created"),
              el("th", {}, "Last used"), el("th", {}, "State"), el("th", {}, "Actions"))),
            this.tokenRows))));
  }

  buildUserForm() {
    const name = el("input", { type: "text", name: "username", required: true, autocomplete: "off", "data-testid": "new-user-name" });
    const password = el("input", { type: "password", name: "password", autocomplete: "new-password", "data-testid": "new-user-password",
      placeholder: "empty: generate one" });
    const role = roleSelect("operator", "role of the new user", { "data-testid": "new-user-role" });
    const error = el("p", { class: "form-error", "data-testid": "user-form-error" });
    const form = el("form", { "data-testid": "user-form" },
      el("label", {}, "Username", name), el("label", {}, "Password", password), el("label", {}, "Role", role),
      el("button", { type: "submit", class: "btn primary", "data-testid": "create-user" }, "Create user"));
    form.addEventListener("submit", async (ev) => {
      ev.preventDefault();
      error.textContent = "";
      const chosen = password.value || newPassword();
      try {
        await api.post("/api/users", { username: name.value.trim(), password: chosen, role: role.value });
      } catch (err) {
        error.textContent = err.message;
        return;
      }
      this.showOnce(`Password of ${name.value.trim()}`, password.value ? null : chosen);
      this.say(`User ${name.value.trim()} created (${role.value}).`);
      form.reset();
      role.value = "operator";
      this.load();
    });
    return { form, error };
  }

  buildTokenForm() {
    const name = el("input", { type: "text", name: "name", required: true, autocomplete: "off", "data-testid": "new-token-name" });
    const role = roleSelect("viewer", "role of the new token", { "data-testid": "new-token-role" }, TOKEN_ROLES);
    // empty: the server's lifetime (FLEET_TOKEN_TTL_DAYS, 90 days by default), which is also the most it allows
    const days = el("input", { type: "text", inputmode: "numeric", name: "days", "data-testid": "new-token-days", placeholder: "server's maximum" });
    const error = el("p", { class: "form-error", "data-testid": "token-form-error" });
    const form = el("form", { "data-testid": "token-form" },
      el("label", {}, "Name", name), el("label", {}, "Role", role), el("label", {}, "Expires in days", days),
      el("button", { type: "submit", class: "btn primary", "data-testid": "create-token" }, "Create token"));
    form.addEventListener("submit", async (ev) => {
      ev.preventDefault();
      error.textContent = "";
      const body = { name: name.value.trim(), role: role.value };
      if (days.value.trim()) {
        const d = Number(days.value);
        if (!Number.isFinite(d) || d <= 0) {
          error.textContent = "Expires in days: a positive number, or empty for the server's maximum.";
          return;
        }
        body.expires_in_s = d * 86400;
      }
      let created;
      try {
        created = await api.post("/api/tokens", body);
      } catch (err) {
        error.textContent = err.message;
        return;
      }
      this.showOnce(`Token ${created.name} (${created.role})`, created.token);
      this.say(`Token ${created.name} created.`);
      form.reset();
      this.load();
    });
    return { form, error };
  }

  /** The secret in a box, once: it is not stored anywhere the page could show it again. */
  showOnce(what, secret) {
    if (!secret) {
      this.secret.hidden = true;
      return;
    }
    const value = el("code", { class: "secret", "data-testid": "shown-once-value" }, secret);
    const copy = el("button", { type: "button", class: "btn small" }, "Copy");
    copy.addEventListener("click", () => navigator.clipboard?.writeText(secret).then(() => (copy.textContent = "Copied")));
    const dismiss = el("button", { type: "button", class: "btn small", "data-testid": "done-hide" }, "Done, hide it");
    dismiss.addEventListener("click", () => {
      this.secret.hidden = true;
      this.secret.replaceChildren();
    });
    this.secret.replaceChildren(el("div", { class: "panel" },
      el("p", {}, el("strong", {}, `${what}: `), "shown only now — copy it and hand it over."), value, " ", copy, " ", dismiss));
    this.secret.hidden = false;
  }

  say(text) {
    this.error.textContent = "";
    this.status.textContent = text;
    announce(text);
  }

  fail(text) {
    this.status.textContent = "";
    this.error.textContent = text;
  }

  async act(promise, done) {
    try {
      await promise;
    } catch (err) {
      this.fail(err.message);
      return;
    }
    this.say(done);
    this.load();
  }

  async open() {
    this.secret.hidden = true;
    this.secret.replaceChildren();
    this.status.textContent = "";
    this.error.textContent = "";
    await this.load();
  }

  async load() {
    await session.ready;
    const admin = session.allows("admin");
    this.denied.hidden = admin;
    this.denied.textContent = admin ? "" : `Users and tokens are for admins (you are ${session.me?.role ?? "not logged in"}).`;
    for (const f of [this.userForm.form, this.tokenForm.form]) for (const c of f.elements) c.disabled = !admin;
    if (!admin) {
      this.userRows.replaceChildren();
      this.tokenRows.replaceChildren();
      return;
    }
    try {
      const [users, tokens] = await Promise.all([api.get("/api/users"), api.get("/api/tokens")]);
      this.renderUsers(users);
      this.renderTokens(tokens);
    } catch (err) {
      this.fail(`Could not load users and tokens: ${err.message}`);
    }
  }

  renderUsers(users) {
    const me = session.me?.username;
    this.userRows.replaceChildren(...users.map((u) => {
      const self = u.username === me;
      const path = `/api/users/${encodeURIComponent(u.username)}`;
      const role = roleSelect(u.role, `role of ${u.username}`, { "data-testid": `role-${u.username}`, disabled: self });
      role.addEventListener("change", () => this.act(api.patch(path, { role: role.value }), `${u.username} is now ${role.value}.`));
      const toggle = u.disabled
        ? el("button", { type: "button", class: "btn small", "data-testid": `enable-${u.username}`,
          onclick: () => this.act(api.patch(path, { disabled: false }), `${u.username} enabled.`) }, "Enable")
        : confirmButton("Disable", "Tap again to disable", { "data-testid": `disable-${u.username}`, disabled: self },
          () => this.act(api.patch(path, { disabled: true }), `${u.username} disabled; their sessions ended.`));
      const reset = confirmButton("Reset password", "Tap again to reset", { "data-testid": `reset-${u.username}` }, async () => {
        const password = newPassword();
        try {
          await api.patch(path, { password });
        } catch (err) {
          this.fail(err.message);
          return;
        }
        this.showOnce(`New password of ${u.username}`, password);
        this.say(`Password of ${u.username} reset; their sessions ended.`);
      });
      return el("tr", { dataset: { testid: `user-${u.username}`, disabled: String(u.disabled), role: u.role } },
        el("td", {}, el("strong", {}, u.username), self ? el("span", { class: "muted" }, " (you)") : null),
        el("td", {}, role),
        el("td", {}, u.disabled ? "disabled" : "active"),
        el("td", { class: "actions" }, toggle, reset,
          self ? el("span", { class: "inline-note", "data-testid": "self-note" }, "Your own account: another admin can change its role or disable it.") : null));
    }));
  }

  renderTokens(tokens) {
    this.tokenRows.replaceChildren(...tokens.map((t) => {
      const revoke = t.revoked ? null : confirmButton("Revoke", "Tap again to revoke", { "data-testid": `revoke-${t.name}` },
        () => this.act(api.del(`/api/tokens/${encodeURIComponent(t.id)}`), `Token ${t.name} revoked.`));
      const expired = t.expires_at != null && t.expires_at * 1000 < Date.now();
      return el("tr", { dataset: { testid: `token-${t.name}`, revoked: String(t.revoked), id: t.id } },
        el("td", {}, el("strong", {}, t.name), el("div", { class: "muted small" }, `by ${t.created_by}${t.owner ? `, answers to ${t.owner}` : ""}`)),
        el("td", {}, t.role),
        el("td", {}, when(t.created_at)),
        el("td", {}, when(t.last_used_at)),
        el("td", {}, t.revoked ? "revoked" : expired ? "expired" : t.expires_at ? `until ${when(t.expires_at)}` : "active"),
        el("td", { class: "actions" }, revoke));
    }));
  }
}
