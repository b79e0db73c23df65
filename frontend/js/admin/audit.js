// Audit trail (admins): who did what, from where, with which token (GET /api/audit, newest first). Filters by
// robot, actor, action and time range; pages backwards ("Older"); CSV export of every entry the filters
// match (fetched page by page, built here: nothing leaves the browser but the API requests).
import { announce } from "../core/a11y.js";
import { api } from "../core/api.js";
import { session } from "../core/session.js";
import { el } from "../core/util.js";

const PAGE = 100;
const EXPORT_PAGE = 1000;
const EXPORT_MAX = 100_000;
// the actions the server records (a free text filter still takes any other)
const ACTIONS = [
  "command", "estop", "estop_release", "hold", "hold_release", "lease_take", "lease_release", "lease_request",
  "lease_grant", "lease_takeover", "alarm_ack", "alarm_rule", "battery_override", "legacy_addressing",
  "robot_forget", "run_start", "run_update", "run_stop", "run_delete", "user_create", "user_update", "user_delete",
  "token_create", "token_revoke",
];
const COLUMNS = ["id", "ts", "time_utc", "actor", "actor_name", "token_id", "client", "action", "robot_id", "detail"];

function when(ts) {
  return new Date(ts * 1000).toLocaleString([], { hour12: false });
}

/** A datetime-local input's value as epoch seconds (local time), or null when empty or unreadable. */
function epoch(input) {
  if (!input.value) return null;
  const ms = new Date(input.value).getTime();
  return Number.isFinite(ms) ? ms / 1000 : null;
}

function csvCell(v) {
  if (v == null) return "";
  const s = typeof v === "object" ? JSON.stringify(v) : String(v);
  return /[",\n\r]/.test(s) ? `"${s.replace(/"/g, '""')}"` : s;
}

export function auditCsv(entries) {
  const rows = entries.map((e) => COLUMNS.map((c) =>
    csvCell(c === "time_utc" ? new Date(e.ts * 1000).toISOString() : c === "ts" ? e.ts : e[c])).join(","));
  return `${COLUMNS.join(",")}\n${rows.map((r) => `${r}\n`).join("")}`;
}

function detailText(detail) {
  const parts = Object.entries(detail ?? {}).map(([k, v]) => `${k}: ${typeof v === "object" && v !== null ? JSON.stringify(v) : v}`);
  return parts.join(" · ");
}

export class AuditView {
  constructor(host) {
    this.host = host;
    this.entries = [];
    this.denied = el("p", { class: "inline-note", "data-testid": "audit-denied", hidden: true });
    this.status = el("p", { class: "form-ok", role: "status", "data-testid": "audit-status" });
    /** counts the loads, and the loads and exports, asked: only the latest one's reply shows */
    this.loads = 0;
    this.actions = 0;
    this.error = el("p", { class: "form-error", "data-testid": "audit-error" });
    const input = (name, label, attrs = {}) => el("label", {}, label,
      el("input", { type: "text", name, autocomplete: "off", "data-testid": `audit-${name}`, ...attrs }));
    const actionList = el("datalist", { id: "audit-actions" }, ...ACTIONS.map((a) => el("option", { value: a })));
    this.form = el("form", { class: "audit-filters", "data-testid": "audit-form" },
      input("robot", "Robot"), input("actor", "Actor (user or token)"),
      input("action", "Action", { list: "audit-actions" }), actionList,
      el("label", {}, "From", el("input", { type: "datetime-local", name: "start", step: "1", "data-testid": "audit-start" })),
      el("label", {}, "To", el("input", { type: "datetime-local", name: "end", step: "1", "data-testid": "audit-end" })),
      el("button", { type: "submit", class: "btn primary", "data-testid": "audit-apply" }, "Show"),
      el("button", { type: "button", class: "btn", "data-testid": "audit-csv", onclick: () => this.exportCsv() }, "Export CSV"));
    this.form.addEventListener("submit", (ev) => {
      ev.preventDefault();
      this.load();
    });
    this.rows = el("tbody", { "data-testid": "audit-rows" });
    this.more = el("button", { type: "button", class: "btn", "data-testid": "audit-more", hidden: true,
      onclick: () => this.load(true) }, "Older entries");
    host.replaceChildren(this.denied, this.status, this.error,
      el("section", { class: "panel", "aria-label": "Audit trail" }, this.form,
        el("div", { class: "table-scroll", tabindex: "0", "aria-label": "Audit entries" },
          el("table", { class: "plain", "data-testid": "audit-table" },
            el("thead", {}, el("tr", {}, ...["Time", "Actor", "Action", "Robot", "Detail", "From"].map((h) => el("th", { scope: "col" }, h)))),
            this.rows)),
        this.more));
  }

  params(limit, beforeId) {
    const f = this.form.elements;
    const p = new URLSearchParams({ limit: String(limit) });
    for (const [key, name] of [["robot_id", "robot"], ["actor", "actor"], ["action", "action"]]) {
      const v = f[name].value.trim();
      if (v) p.set(key, v);
    }
    const start = epoch(f.start);
    const end = epoch(f.end);
    if (start != null) p.set("start", String(start));
    if (end != null) p.set("end", String(end));
    if (beforeId != null) p.set("before_id", String(beforeId));
    return p;
  }

  async open() {
    this.status.textContent = "";
    this.error.textContent = "";
    await this.load();
  }

  async load(older = false) {
    const load = ++this.loads; // only the latest load's rows are shown
    const action = ++this.actions; // and the status says what the latest action did (an export may end first)
    await session.ready;
    const admin = session.allows("admin");
    this.denied.hidden = admin;
    this.denied.textContent = admin ? "" : `The audit trail is for admins (you are ${session.me?.role ?? "not logged in"}).`;
    for (const c of this.form.elements) c.disabled = !admin;
    if (!admin) {
      this.entries = [];
      this.rows.replaceChildren();
      this.more.hidden = true;
      return;
    }
    const before = older && this.entries.length ? this.entries[this.entries.length - 1].id : null;
    let page;
    try {
      page = await api.get(`/api/audit?${this.params(PAGE, before)}`);
    } catch (err) {
      this.error.textContent = `Could not load the audit trail: ${err.message}`;
      return;
    }
    if (load !== this.loads) return; // a later load shows its rows
    this.error.textContent = "";
    this.entries = older ? [...this.entries, ...page] : page;
    this.more.hidden = page.length < PAGE;
    this.render();
    if (action === this.actions) {
      this.status.textContent = `${this.entries.length} entr${this.entries.length === 1 ? "y" : "ies"} shown, newest first.`;
    }
  }

  render() {
    this.rows.replaceChildren(...this.entries.map((e) => el("tr", { dataset: { testid: "audit-row", action: e.action, id: String(e.id) } },
      el("td", {}, when(e.ts)),
      el("td", {}, el("strong", {}, e.actor_name), e.actor !== e.actor_name ? el("div", { class: "muted small" }, e.actor) : null),
      el("td", {}, e.action),
      el("td", {}, e.robot_id ?? "—"),
      el("td", { class: "audit-detail" }, detailText(e.detail)),
      el("td", {}, e.client || "—", e.token_id ? el("div", { class: "muted small" }, e.token_id) : null))));
  }

  /** Every entry the filters match, page by page (up to EXPORT_MAX), as a CSV download. */
  async exportCsv() {
    const action = ++this.actions;
    const all = [];
    let before = null;
    try {
      while (all.length < EXPORT_MAX) {
        const page = await api.get(`/api/audit?${this.params(EXPORT_PAGE, before)}`);
        all.push(...page);
        if (page.length < EXPORT_PAGE) break;
        before = page[page.length - 1].id;
      }
    } catch (err) {
      this.error.textContent = `Export failed: ${err.message}`;
      return;
    }
    const url = URL.createObjectURL(new Blob([auditCsv(all)], { type: "text/csv" }));
    const a = el("a", { href: url, download: `audit-${new Date().toISOString().slice(0, 19).replace(/:/g, "")}.csv` });
    document.body.append(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(url), 10_000);
    const text = `Exported ${all.length} audit entries as CSV.`;
    if (action === this.actions) this.status.textContent = text;
    announce(text);
  }
}
