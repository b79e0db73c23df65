// The mission panel on the fleet map: a compact overlay in the map's top-left corner (it never moves the
// page's layout: it floats over the map, collapsed to one line by default) showing the newest running or
// paused mission (state, covered %, time left), with Pause / Resume / Abort and a link to the Missions page.
// Hidden while no mission runs or is paused. It follows the live socket (store.js: the snapshot's missions,
// then each pushed change): nothing is polled. Viewers see it read-only; the server enforces the roles.
import { api } from "../core/api.js";
import { session } from "../core/session.js";
import { store } from "../core/store.js";
import { el } from "../core/util.js";

export class MissionOverlay {
  constructor(host, { map = null, source = store } = {}) {
    this.host = host;
    this.map = map;
    this.source = source;
    this.mission = null;
    this.summary = el("summary", { "data-testid": "mission-overlay-summary" }, "Mission");
    this.line = el("div", { class: "muted", role: "status", "data-testid": "mission-overlay-status" });
    this.buttons = {
      pause: this.button("Pause", "pause"),
      resume: this.button("Resume", "resume"),
      abort: this.button("Abort", "abort"),
    };
    this.root = el(
      "details",
      { class: "mission-overlay", "data-testid": "mission-overlay", hidden: true },
      this.summary,
      el("div", { class: "mission-overlay-body" },
        this.line,
        el("div", { class: "row" }, this.buttons.pause, this.buttons.resume, this.buttons.abort),
        this.eta = el("div", { class: "muted", "data-testid": "mission-overlay-eta" }),
        this.link = el("a", { href: "/missions", "data-link": true, "data-testid": "mission-overlay-link" }, "Missions page"),
      ),
    );
    host.append(this.root);
    source.on("missions", () => this.follow());
    this.follow();
  }

  button(label, action) {
    return el("button", {
      type: "button",
      "data-testid": `mission-overlay-${action}`,
      onclick: () => this.act(action),
    }, label);
  }

  async act(action) {
    if (!this.mission) return;
    let answer;
    try {
      answer = await api.post(`/api/missions/${this.mission.id}/${action}`, {});
    } catch (err) {
      this.line.textContent = `Refused: ${err.message}`;
      return;
    }
    if (answer?.id) this.source.setMission(answer); // the socket says the same a moment later
  }

  /** The newest mission that runs or is paused; once it ends, its final state stays shown until another
   * starts. */
  follow() {
    const all = [...this.source.missions.values()];
    const live = all.filter((m) => m.state === "running" || m.state === "paused")
      .sort((a, b) => a.created_at - b.created_at).at(-1);
    this.mission = live ?? (this.mission && this.source.missions.get(this.mission.id)) ?? null;
    this.render();
  }

  render() {
    const m = this.mission;
    this.root.hidden = !m;
    if (!m) return;
    if (this.map) this.host.style.top = `${this.map.offsetTop + 6}px`; // over the map, under the panel's head
    const pct = (m.covered_fraction * 100).toFixed(0);
    const can = session.allows("operator");
    this.summary.textContent = `Mission ${m.state} · ${pct}% covered`;
    // under the buttons: a time left that changes length never moves them
    this.eta.textContent = m.state === "running" && m.eta_s != null ? `about ${Math.ceil(m.eta_s / 60)} min left` : "";
    this.root.dataset.state = m.state;
    this.link.href = `/missions/${encodeURIComponent(m.id)}`;
    this.root.dataset.covered = String(m.covered_fraction);
    this.line.textContent = `${m.name}${m.reason ? ` (${m.reason})` : ""}`;
    this.buttons.pause.disabled = !can || m.state !== "running";
    this.buttons.resume.disabled = !can || m.state !== "paused";
    this.buttons.abort.disabled = !can || !["running", "paused"].includes(m.state);
  }
}
