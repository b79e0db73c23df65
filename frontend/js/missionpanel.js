// The mission panel on the fleet map: a compact overlay in the map's top-left corner (it never moves the
// page's layout: it floats over the map, collapsed to one line by default) showing the newest running or
// paused mission (state, covered %), with Pause / Resume / Abort and a link to the Missions page. Hidden while
// no mission runs or is paused. Viewers see it read-only; the server enforces the roles either way.
import { api } from "./api.js";
import { session } from "./session.js";
import { el } from "./util.js";

const POLL_MS = 2000;

export class MissionOverlay {
  constructor(host, { map = null, isVisible = () => true } = {}) {
    this.host = host;
    this.map = map;
    this.isVisible = isVisible;
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
        el("a", { href: "/missions", "data-link": true, "data-testid": "mission-overlay-link" }, "Missions page"),
      ),
    );
    host.append(this.root);
    this.poll();
    this.timer = setInterval(() => this.poll(), POLL_MS);
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
    try {
      await api.post(`/api/missions/${this.mission.id}/${action}`, {});
    } catch (err) {
      this.line.textContent = `Refused: ${err.message}`;
      return;
    }
    await this.poll(true);
  }

  async poll(force = false) {
    if (!force && !this.isVisible()) return;
    let list;
    try {
      list = await api.get("/api/missions");
    } catch {
      return; // next poll
    }
    // the newest mission that runs or is paused; once it ends, its final state stays shown until another starts
    const live = list.find((m) => m.state === "running" || m.state === "paused");
    const shown = live || (this.mission && list.find((m) => m.id === this.mission.id));
    this.mission = shown || null;
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
    this.root.dataset.state = m.state;
    this.root.dataset.covered = String(m.covered_fraction);
    this.line.textContent = `${m.name}${m.reason ? ` (${m.reason})` : ""}`;
    this.buttons.pause.disabled = !can || m.state !== "running";
    this.buttons.resume.disabled = !can || m.state !== "paused";
    this.buttons.abort.disabled = !can || !["running", "paused"].includes(m.state);
  }
}
