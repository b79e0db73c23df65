// The missions page's list: every mission with its state, robots, progress, when it started and ended and a
// link to the run it recorded. Read once (GET /api/missions), then kept up to date from the live socket
// (store.js: each pushed change of a mission): nothing is polled. A row's button opens the mission.
import { store } from "../core/store.js";
import { el } from "../core/util.js";

const COLUMNS = ["Mission", "State", "Robots", "Covered", "Started", "Ended", "Run"];

function clock(ts) {
  return ts == null ? "—" : new Date(ts * 1000).toLocaleString([], { dateStyle: "short", timeStyle: "medium" });
}

export class MissionList {
  /** ``onOpen(id)``: a row's mission was chosen. */
  constructor(host, { onOpen, source = store }) {
    this.onOpen = onOpen;
    this.source = source;
    this.rows = new Map(); // id -> summary (MissionSummary, or a pushed MissionPublic)
    this.selected = null;
    this.body = el("tbody", { "data-testid": "mission-list-rows" });
    this.empty = el("p", { class: "muted", "data-testid": "mission-list-empty" }, "No mission yet.");
    host.append(
      el("div", { class: "panel-head" }, el("h2", {}, "Missions")),
      el("div", { class: "table-scroll", tabindex: "0", role: "region", "aria-label": "Missions" },
        el("table", { class: "missions-table", "data-testid": "mission-list" },
          el("thead", {}, el("tr", {}, ...COLUMNS.map((c) => el("th", { scope: "col" }, c)))),
          this.body)),
      this.empty,
    );
    source.on("missions", (id) => this.heard(id));
  }

  /** The list as the server has it now (at load, and after the page made a mission). */
  set(summaries) {
    this.rows = new Map(summaries.map((m) => [m.id, m]));
    for (const m of this.source.missions.values()) this.rows.set(m.id, { ...this.rows.get(m.id), ...m });
    this.render();
  }

  heard(id) {
    const ids = id == null ? [...this.source.missions.keys()] : [id];
    for (const i of ids) {
      const m = this.source.missions.get(i);
      if (m) this.rows.set(i, { ...this.rows.get(i), ...m });
    }
    this.render();
  }

  select(id) {
    this.selected = id;
    this.render();
  }

  render() {
    const all = [...this.rows.values()].sort((a, b) => b.created_at - a.created_at);
    this.empty.hidden = all.length > 0;
    this.body.replaceChildren(...all.map((m) => {
      const runId = m.run_id;
      return el("tr", { "data-testid": `mission-row-${m.id}`, "data-state": m.state,
        "aria-current": m.id === this.selected ? "true" : null, class: m.id === this.selected ? "selected" : "" },
      el("td", {}, el("button", { type: "button", class: "link", "data-testid": `mission-open-${m.id}`,
        onclick: () => this.onOpen(m.id) }, m.name || m.id), el("span", { class: "muted" }, ` ${m.type}`)),
      el("td", {}, m.state, m.reason ? el("span", { class: "muted" }, ` (${m.reason})`) : ""),
      el("td", {}, m.robots.join(", ")),
      el("td", {}, `${(m.covered_fraction * 100).toFixed(0)}%`),
      el("td", {}, clock(m.started_at)),
      el("td", {}, clock(m.ended_at)),
      el("td", {}, runId == null ? "—" : el("a", { href: `/runs/${runId}`, "data-link": true,
        "data-testid": `mission-run-${m.id}` }, `run ${runId}`)));
    }));
  }
}
