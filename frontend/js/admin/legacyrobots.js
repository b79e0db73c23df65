// Robots on the old Mollusca framework (admins): which may speak on its anonymous topics. The old framework
// names its robot inside each message and cannot log in, so the server takes such messages only for robots
// registered here (PUT/DELETE /api/robots/{id}/legacy); every other one is refused and counted.
import { announce } from "../core/a11y.js";
import { api } from "../core/api.js";
import { session } from "../core/session.js";
import { store } from "../core/store.js";
import { el } from "../core/util.js";

const ID_PATTERN = "[A-Za-z0-9_-]{1,64}";

export class LegacyRobotsView {
  constructor(host) {
    this.rows = el("tbody", { "data-testid": "legacy-rows" });
    this.status = el("p", { class: "form-ok", role: "status", "data-testid": "legacy-status" });
    this.error = el("p", { class: "form-error", "data-testid": "legacy-error" });
    this.form = this.buildForm();
    this.section = el("section", { class: "panel", "aria-labelledby": "legacy-h", "data-testid": "legacy-robots" },
      el("h2", { id: "legacy-h", class: "panel-title" }, "Robots on the old framework"),
      el("p", { class: "muted" }, "Their messages on robot/sensor_data/… are anonymous and name the robot: only the " +
        "robots listed here are heard. Remove a robot once it runs the agent."),
      this.form, this.status, this.error,
      el("table", { class: "plain", "data-testid": "legacy-table" },
        el("thead", {}, el("tr", {}, el("th", {}, "Robot"), el("th", {}, "Command topic"), el("th", {}, "State"),
          el("th", {}, "Actions"))),
        this.rows));
    host.replaceChildren(this.section);
    // live: a robot registered here shows online as soon as its first message is taken
    store.on("robots", () => {
      if (!this.section.hidden && this.section.isConnected && host.offsetParent !== null) this.render([...store.robots.values()]);
    });
  }

  buildForm() {
    const name = el("input", { type: "text", name: "robot", required: true, autocomplete: "off", pattern: ID_PATTERN,
      title: "letters, digits, - and _ (the robot_id its messages carry)", "data-testid": "legacy-new-id" });
    const topic = el("select", { "aria-label": "command topic it listens on", "data-testid": "legacy-new-topic" },
      el("option", { value: "shared" }, "shared (robot/control/commands: the seed's code)"),
      el("option", { value: "own" }, "its own ({id}/control/commands)"));
    const form = el("form", { "data-testid": "legacy-form" },
      el("label", {}, "Robot id", name), el("label", {}, "Listens on", topic),
      el("button", { type: "submit", class: "btn primary", "data-testid": "legacy-register" }, "Register"));
    form.addEventListener("submit", (ev) => {
      ev.preventDefault();
      const id = name.value.trim();
      this.act(api.put(`/api/robots/${encodeURIComponent(id)}/legacy`, { listens_on: topic.value }),
        `${id} registered: its old-framework messages are taken.`, () => form.reset());
    });
    return form;
  }

  async act(promise, done, after) {
    this.error.textContent = "";
    try {
      await promise;
    } catch (err) {
      this.status.textContent = "";
      this.error.textContent = err.message;
      return;
    }
    this.status.textContent = done;
    announce(done);
    after?.();
    await this.load();
  }

  async load() {
    await session.ready;
    const admin = session.allows("admin");
    this.section.hidden = !admin;
    if (!admin) return;
    let robots;
    try {
      robots = await api.get("/api/robots");
    } catch (err) {
      this.error.textContent = `Could not load the robots: ${err.message}`;
      return;
    }
    this.render(robots);
  }

  /** Re-rendered only when a row would change, so that a button never moves or vanishes under a finger. */
  render(robots) {
    const legacy = robots.filter((r) => r.legacy).sort((a, b) => a.id.localeCompare(b.id));
    const key = JSON.stringify(legacy.map((r) => [r.id, r.legacy_listens_on, r.online]));
    if (this.rows.dataset.key === key) return;
    this.rows.dataset.key = key;
    this.rows.replaceChildren(...legacy.map((r) => {
      const remove = el("button", { type: "button", class: "btn small", "data-testid": `legacy-remove-${r.id}` }, "Remove");
      remove.addEventListener("click", () => this.act(api.del(`/api/robots/${encodeURIComponent(r.id)}/legacy`),
        `${r.id} removed: its old-framework messages are refused.`));
      return el("tr", { dataset: { testid: `legacy-${r.id}` } },
        el("td", {}, el("strong", {}, r.id)),
        el("td", {}, r.legacy_listens_on === "own" ? `${r.id}/control/commands` : "robot/control/commands (shared)"),
        el("td", {}, r.online ? "online" : "offline"),
        el("td", { class: "actions" }, remove));
    }));
  }
}
