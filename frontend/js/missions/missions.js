// Missions page (/missions, /missions/{id}): a researcher's workplace. The pool map is the fleet page's own
// (map/fleetmap.js: metres, axes, the site, live robots) with the mission layer (missionlayer.js: the plan and
// the swept area); beside it the editor (draw an area on the map or take the whole pool, pick robots and the
// sweep width, preview the plan, rehearse it in the server's twin of the fleet: rehearsal.js), the mission at
// work (state, covered %, time left, each robot's share, its events) or, once it ended, its report with a link
// to its run; under them the list of every mission (missionlist.js). A formation mission instead: the clicked
// points are the leader's path, and the other robots hold slots in a V behind it, `spacing` apart (the server
// runs the formation law; docs/missions.md).
// Everything live comes pushed on the socket (store.js); a mission opened is read once, never polled.
// Viewers see it read-only; the server enforces the roles either way.
import { api } from "../core/api.js";
import { robotColor } from "../core/robotcolor.js";
import { store } from "../core/store.js";
import { el } from "../core/util.js";
import { FleetMap } from "../map/fleetmap.js";
import { MissionEditor } from "./missioneditor.js";
import { MissionLayer } from "./missionlayer.js";
import { MissionList } from "./missionlist.js";
import { missionReport } from "./missionreport.js";
import { MissionRehearsal } from "./rehearsal.js";

const ENDED = ["completed", "aborted", "failed"];

export class MissionsPanel {
  constructor(host) {
    this.host = host;
    this.mission = null; // the mission opened (a draft, running, or ended)
    this.coverage = new Map(); // mission id -> swept area read once (a mission not pushed any more)
    const mapEl = el("div", { id: "missions-map", class: "map", "data-testid": "mission-map" });
    this.side = el("section", { class: "panel mission-side", "aria-label": "Mission", "data-testid": "missions-panel" });
    const listHost = el("section", { class: "panel mission-list-panel", "aria-label": "Missions list" });
    host.append(
      el("section", { class: "panel map-panel mission-map-panel", "aria-label": "Mission map" },
        el("div", { class: "panel-head" }, el("h2", {}, "Pool map"),
          el("span", { class: "muted" }, "click corners of the area, or the leader's path")),
        mapEl),
      this.side,
      listHost,
    );
    this.map = new FleetMap(mapEl, { onSelect: () => {} });
    // a refused rehearsal is said where the editor says its own refusals
    this.rehearsal = new MissionRehearsal(this.map, { say: (text) => (this.editor.error.textContent = text) });
    this.editor = new MissionEditor(this.side, this.map, { onCreate: (body) => this.create(body),
      onAction: (name) => this.action(name), besidePlan: [this.rehearsal.button] });
    this.status = el("div", { class: "muted", role: "status", "data-testid": "mission-status" });
    this.shares = el("ul", { class: "mission-shares", "data-testid": "mission-shares" });
    this.report = el("div", { class: "mission-report", "data-testid": "mission-report", hidden: true });
    this.events = el("ul", { class: "mission-events", "data-testid": "mission-events" });
    // the rehearsal's figures come under the controls: their arrival moves no button the user may press
    this.side.append(this.rehearsal.block, this.status, this.shares, this.report, this.events);
    this.layer = new MissionLayer(this.map, {
      shown: () => (this.mission ? [this.mission] : []),
      sweptOf: (id) => store.swept.get(id) ?? this.coverage.get(id),
    });
    this.list = new MissionList(listHost, { onOpen: (id) => this.navigateTo(id) });
    store.on("missions", (id) => this.heard(id));
    this.loaded = this.load();
  }

  async load() {
    try {
      this.list.set(await api.get("/api/missions"));
    } catch (err) {
      this.status.textContent = `Missions not loaded: ${err.message}`;
    }
  }

  /** The page was opened (``id``: /missions/{id}, or null: the newest mission at work, if any). */
  async open(id) {
    await this.loaded;
    if (id == null) {
      const live = [...this.list.rows.values()].filter((m) => ["running", "paused", "draft"].includes(m.state))
        .sort((a, b) => b.created_at - a.created_at)[0];
      id = live?.id ?? this.mission?.id ?? null;
    }
    if (id == null) return this.render();
    await this.follow(id);
  }

  navigateTo(id) {
    history.pushState({}, "", `/missions/${encodeURIComponent(id)}`);
    this.follow(id);
  }

  /** Read the mission once (its events and transitions too), and its swept area if none is pushed. */
  async follow(id) {
    try {
      const m = await api.get(`/api/missions/${encodeURIComponent(id)}`);
      const pushed = store.missions.get(id);
      // the socket's pushes carry no report figures (separation): those of the read stay
      this.mission = pushed && pushed.updated_at > m.updated_at
        ? { ...m, ...pushed, events: m.events, separation: m.separation } : m;
      if (!store.swept.has(id) && m.state !== "draft") {
        this.coverage.set(id, await api.get(`/api/missions/${encodeURIComponent(id)}/coverage`));
      }
    } catch (err) {
      this.status.textContent = `Mission ${id} not loaded: ${err.message}`;
      return;
    }
    this.list.select(id);
    this.layer.changed();
    this.render();
  }

  /** A pushed change: the mission opened follows it (its swept area too, by the layer). */
  heard(id) {
    const m = this.mission;
    if (!m || (id != null && id !== m.id)) return;
    const pushed = store.missions.get(m.id);
    if (!pushed) return;
    const ended = !ENDED.includes(m.state) && ENDED.includes(pushed.state);
    this.mission = { ...m, ...pushed, events: pushed.events?.length ? pushed.events : m.events,
      separation: pushed.separation ?? m.separation };
    if (ended) this.follow(m.id); // its report: the final figures, events and run, read once
    else this.render();
  }

  async create(body) {
    const m = await api.post("/api/missions", body);
    this.editor.setArea([]);
    store.setMission(m);
    this.navigateTo(m.id);
  }

  async action(name) {
    if (!this.mission) return;
    const m = await api.post(`/api/missions/${encodeURIComponent(this.mission.id)}/${name}`, {});
    // The store tells heard() at once, as it does the socket's push of the same change, which may come first
    // or after this answer: whichever tells the page the mission ended reads the report, once, and the answer
    // (it carries no report figures) never takes the separation away.
    store.setMission(m);
  }

  render() {
    const m = this.mission;
    this.editor.render(m);
    this.rehearsal.show(m);
    this.layer.describe();
    if (!m) {
      this.status.textContent = this.editor.hint();
      delete this.status.dataset.state;
      this.shares.replaceChildren();
      this.report.hidden = true;
      this.events.replaceChildren();
      return;
    }
    const pct = (m.covered_fraction * 100).toFixed(1);
    const eta = m.state === "running" && m.eta_s != null ? ` · ${Math.ceil(m.eta_s)} s left` : "";
    this.status.textContent = `${m.name || m.id}: ${m.state}${m.reason ? ` (${m.reason})` : ""} · covered ${pct}%`
      + ` · ${Math.round(m.elapsed_s)} s${eta}`;
    this.status.dataset.state = m.state;
    this.status.dataset.covered = String(m.covered_fraction);
    const swept = (m.progress ?? []).reduce((s, p) => s + p.swept_m2, 0);
    this.shares.replaceChildren(...(m.progress ?? []).map((p) => el("li", { "data-robot": p.robot_id },
      el("span", { class: "robot-dot", style: `background:${robotColor(p.robot_id)}` }),
      `${p.robot_id}: ${p.status} · ${(p.fraction * 100).toFixed(0)}% of its path · `
      + `${swept > 0 ? ((p.swept_m2 / swept) * 100).toFixed(0) : 0}% of the swept area (${p.swept_m2.toFixed(2)} m²)`)));
    this.report.hidden = !ENDED.includes(m.state);
    if (!this.report.hidden) this.report.replaceChildren(...missionReport(m));
    this.events.replaceChildren(...(m.events ?? []).slice(-8).map((e) => el("li", { "data-kind": e.kind }, eventText(e))));
  }

  /** Where a point of the pool (metres) is on screen (tests click there). */
  clientAt(x, y) {
    return this.map.toClient(x, y);
  }
}

/** One line of a mission's event list. */
export function eventText(e) {
  const d = e.detail || {};
  if (e.kind === "hand_near") {
    return `hand-driven robot ${e.robot_id} near ${d.near} (${Number(d.distance_m).toFixed(2)} m, under ${Number(d.limit_m).toFixed(2)} m)`;
  }
  if (e.kind === "too_close") {
    return `${e.robot_id} and ${d.near} closer than ${Number(d.limit_m).toFixed(2)} m (${Number(d.distance_m).toFixed(2)} m)`;
  }
  return `${e.kind} ${e.robot_id ?? ""} ${d.reason ?? d.for ?? ""}`.trim();
}

export function setupMissions() {
  const host = document.getElementById("missions-host");
  return host ? new MissionsPanel(host) : null;
}

