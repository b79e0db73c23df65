// "Edit site" (admins): the pool's boundary, keep-outs, geofence margin, the robots' safety filter (minimum
// separation, avoidance on or off, its margin and creep speed) and wall tags as text, saved with
// PUT /api/site as a new version (DELETE: "no site", no fence). The server checks everything; its 422
// (message and code) is shown inline and nothing changes. Other roles see only which version is in force.
import { api } from "../core/api.js";
import { session } from "../core/session.js";
import { store } from "../core/store.js";
import { ago, el } from "../core/util.js";

const pretty = (v) => JSON.stringify(v ?? []);

export class SiteEditor {
  /** ``onSaved(site)``: the new current site (GET /api/site's shape), e.g. for the map to draw. */
  constructor(host, { onSaved } = {}) {
    this.onSaved = onSaved ?? (() => {});
    this.site = null;
    const field = (name, label, hint, rows = 2) => {
      const id = `site-${name}`;
      const input = el("textarea", { id, rows, spellcheck: "false", "data-testid": id, class: "site-json" });
      return [input, el("label", { for: id }, label, " ", el("span", { class: "muted" }, hint)), input];
    };
    const [boundary, ...boundaryRow] = field("boundary", "Boundary", "[[x, y], …] metres, at least 3 corners");
    const [keepouts, ...keepoutRow] = field("keepouts", "Keep-outs", "[[[x, y], …], …] polygons inside the boundary");
    const [tags, ...tagRow] = field("tags", "Wall tags", '[{"id", "size_m", "pose": {"x", "y", "z", "yaw"}}, …]');
    this.inputs = { boundary, keepouts, tags };
    this.margin = el("input", {
      id: "site-margin", type: "number", min: "0", max: "10", step: "0.01", "data-testid": "site-margin",
    });
    const number = (name, max, step) =>
      el("input", { id: `site-${name}`, type: "number", min: "0", max, step, "data-testid": `site-${name}` });
    this.separation = number("separation", "10", "0.01");
    this.avoidance = el("input", { id: "site-avoidance", type: "checkbox", "data-testid": "site-avoidance" });
    this.avoidMargin = number("avoid-margin", "2", "0.01");
    this.creep = number("creep", "0.5", "0.01");
    this.status = el("p", { class: "muted", "data-testid": "site-line" }, "loading…");
    this.error = el("p", { class: "site-error", role: "alert", "data-testid": "site-error", hidden: true });
    this.save = el("button", { type: "submit", class: "btn primary", "data-testid": "site-save" }, "Save new version");
    this.clear = el("button", { type: "button", class: "btn", "data-testid": "site-clear" }, "No site (no fence)");
    this.clear.addEventListener("click", () => this.removeSite());
    this.form = el("form", { class: "site-form", "data-testid": "site-form" },
      ...boundaryRow, ...keepoutRow,
      el("label", { for: "site-margin" }, "Geofence margin (m)"), this.margin,
      el("label", { for: "site-separation" }, "Robots kept apart (m, centre to centre)"), this.separation,
      el("label", { for: "site-avoidance" }, this.avoidance, " Safety filter on the robots (robots never collide)"),
      el("label", { for: "site-avoid-margin" }, "Filter margin (m)"), this.avoidMargin,
      el("label", { for: "site-creep" }, "Creep speed near a stale neighbour (m/s)"), this.creep,
      ...tagRow, this.error, el("div", { class: "site-actions" }, this.save, this.clear));
    this.form.addEventListener("submit", (ev) => {
      ev.preventDefault();
      this.submit();
    });
    this.details = el("details", { class: "site-edit", "data-testid": "site-edit" },
      el("summary", {}, "Edit site"), this.form);
    host.append(this.status, this.details);
    store.on("session", () => this.applyRole());
    this.applyRole();
    this.load();
  }

  applyRole() {
    this.details.hidden = !(session.me && session.me.role === "admin");
  }

  async load() {
    try {
      this.show(await api.get("/api/site"));
    } catch (err) {
      this.status.textContent = `site unavailable: ${err.message}`;
    }
  }

  show(site) {
    this.site = site;
    const when = site.updated_at ? ago(site.updated_at) : "";
    this.status.textContent = site.configured
      ? `Site v${site.version} · set by ${site.updated_by} ${when}`
      : `No site (v${site.version}): no geofence · set by ${site.updated_by} ${when}`;
    this.status.dataset.version = String(site.version);
    this.inputs.boundary.value = pretty(site.boundary);
    this.inputs.keepouts.value = pretty(site.keepouts);
    this.inputs.tags.value = pretty(site.tags);
    this.margin.value = site.geofence_margin_m ?? 0.15;
    this.separation.value = site.min_separation_m ?? 0.3;
    const avoidance = site.avoidance ?? { enabled: true, margin_m: 0.03, creep_mps: 0.03 };
    this.avoidance.checked = avoidance.enabled;
    this.avoidMargin.value = avoidance.margin_m;
    this.creep.value = avoidance.creep_mps;
  }

  fail(message) {
    this.error.textContent = message;
    this.error.hidden = false;
  }

  /** The form as a PUT body; a field that is not JSON is named before anything is sent. */
  body() {
    const out = {};
    for (const [name, input] of Object.entries(this.inputs)) {
      const text = input.value.trim();
      if (!text && name !== "boundary") continue;
      try {
        out[name] = JSON.parse(text);
      } catch {
        throw new Error(`${name}: not valid JSON`);
      }
    }
    if (this.margin.value !== "") out.geofence_margin_m = Number(this.margin.value);
    // what the form does not edit is kept as it is
    if (this.site?.base_stations?.length) out.base_stations = this.site.base_stations;
    if (this.separation.value !== "") out.min_separation_m = Number(this.separation.value);
    else if (this.site?.min_separation_m != null) out.min_separation_m = this.site.min_separation_m;
    if (this.site?.avoidance || this.avoidMargin.value !== "") {
      out.avoidance = {
        enabled: this.avoidance.checked,
        margin_m: Number(this.avoidMargin.value || 0.03),
        creep_mps: Number(this.creep.value || 0.03),
      };
    }
    return out;
  }

  async submit() {
    this.error.hidden = true;
    let body;
    try {
      body = this.body();
    } catch (err) {
      this.fail(err.message);
      return;
    }
    await this.send(() => api.put("/api/site", body));
  }

  async removeSite() {
    this.error.hidden = true;
    if (this.clear.dataset.armed !== "1") { // a second press confirms: robots lose their fence
      this.clear.dataset.armed = "1";
      this.clear.textContent = "Press again: remove the fence";
      setTimeout(() => {
        delete this.clear.dataset.armed;
        this.clear.textContent = "No site (no fence)";
      }, 4000);
      return;
    }
    delete this.clear.dataset.armed;
    this.clear.textContent = "No site (no fence)";
    await this.send(() => api.del("/api/site"));
  }

  async send(call) {
    this.save.disabled = this.clear.disabled = true;
    try {
      const site = await call();
      this.show(site);
      this.onSaved(site);
    } catch (err) {
      this.fail(err.code ? `${err.message} (${err.code})` : err.message);
    } finally {
      this.save.disabled = this.clear.disabled = false;
    }
  }
}
