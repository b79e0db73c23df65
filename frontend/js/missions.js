// Missions page (/missions): draw an area on a small pool map (or take the whole pool), pick robots and the
// sweep width, preview the plan (parts, paths, estimated time), Start / Pause / Resume / Abort, and watch
// the coverage the robots actually swept fill in (GET /api/missions/{id}/coverage, from their tracks).
// A formation mission instead: the clicked points are the leader's path, and the other robots hold slots in
// a V behind it, `spacing` apart (the server runs the formation law; docs/missions.md).
// Viewers see it read-only; the server enforces the roles either way.
import { api } from "./api.js";
import { robotColor } from "./robotcolor.js";
import { session } from "./session.js";
import { el } from "./util.js";

const SVG = "http://www.w3.org/2000/svg";
const POLL_MS = 1000;

function svg(tag, attrs = {}) {
  const node = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  return node;
}

function ringsOf(geom) {
  if (!geom || !geom.type) return [];
  if (geom.type === "Polygon") return [geom.coordinates];
  if (geom.type === "MultiPolygon") return geom.coordinates;
  if (geom.type === "GeometryCollection") return geom.geometries.flatMap(ringsOf);
  return [];
}

export class MissionsPanel {
  constructor(host) {
    this.host = host;
    this.boundary = [[-2, -2], [2, -2], [2, 2], [-2, 2]];
    this.area = []; // corners clicked on the map ([] = the whole pool)
    this.mission = null;
    this.coverage = null;
    this.robots = [];
    this.timer = null;
    this.build();
    this.load();
  }

  build() {
    this.map = svg("svg", { class: "mission-map", "data-testid": "mission-map", role: "img" });
    this.map.setAttribute("aria-label", "Mission map: click to add corners of the area");
    this.map.style.cssText = "width:100%;max-width:320px;aspect-ratio:1;background:var(--panel-2,#0b2030);cursor:crosshair";
    this.map.addEventListener("click", (ev) => this.addCorner(ev));
    // fixed heights: robots and status arriving later must not move the rest of the page
    this.robotBox = el("div", { class: "mission-robots", "data-testid": "mission-robots",
      style: "height:4.5em;overflow:auto" });
    this.width = el("input", { type: "number", min: "0.05", max: "2", step: "0.05", value: "0.25",
      "aria-label": "Sweep width (m)", "data-testid": "mission-width", style: "width:5em" });
    this.type = el("select", { "aria-label": "Mission type", "data-testid": "mission-type" },
      el("option", { value: "coverage" }, "Coverage sweep"), el("option", { value: "formation" }, "Formation"));
    this.type.addEventListener("change", () => { this.area = []; this.draw(); });
    this.leader = el("select", { "aria-label": "Leader", "data-testid": "mission-leader" });
    this.spacing = el("input", { type: "number", min: "0.3", max: "1.5", step: "0.05", value: "0.5",
      "aria-label": "Formation spacing (m)", "data-testid": "mission-spacing", style: "width:5em" });
    this.loop = el("input", { type: "checkbox", checked: true, "data-testid": "mission-loop" });
    this.coverageRow = el("div", { class: "row" }, el("label", {}, " width ", this.width, " m"));
    this.formationRow = el("div", { class: "row", hidden: true, "data-testid": "mission-formation-row" },
      el("label", {}, "leader ", this.leader), el("label", {}, " spacing ", this.spacing, " m"),
      el("label", {}, " ", this.loop, " loop"));
    this.status = el("div", { class: "muted", role: "status", "data-testid": "mission-status",
      style: "height:4em;overflow:auto" });
    this.events = el("ul", { class: "mission-events", "data-testid": "mission-events" });
    const button = (label, testid, fn) =>
      el("button", { type: "button", class: "btn", "data-testid": testid, onclick: () => this.act(fn) }, label);
    this.buttons = {
      pool: button("Whole pool", "mission-pool", async () => { this.area = []; this.draw(); }),
      plan: button("Preview plan", "mission-plan", () => this.create()),
      start: button("Start", "mission-start", () => this.action("start")),
      pause: button("Pause", "mission-pause", () => this.action("pause")),
      resume: button("Resume", "mission-resume", () => this.action("resume")),
      abort: button("Abort", "mission-abort", () => this.action("abort")),
    };
    this.coverageRow.prepend(this.buttons.pool);
    this.robotBox.addEventListener("change", () => this.fillLeader());
    this.host.append(
      el("section", { class: "panel-section", "aria-label": "Mission", "data-testid": "missions-panel" },
        this.map,
        el("div", { class: "row" }, this.type),
        this.coverageRow,
        this.formationRow,
        this.robotBox,
        el("div", { class: "row" }, ...["plan", "start", "pause", "resume", "abort"].map((k) => this.buttons[k])),
        this.status,
        this.events,
      ),
    );
    this.draw();
  }

  async load() {
    try {
      const site = await api.get("/api/site");
      if (site?.boundary) this.boundary = site.boundary;
    } catch { /* the default pool */ }
    await this.refreshRobots();
    try {
      const list = await api.get("/api/missions");
      const live = list.find((m) => ["running", "paused", "draft"].includes(m.state));
      if (live) await this.follow(live.id);
    } catch { /* nothing yet */ }
    this.draw();
  }

  async refreshRobots() {
    try {
      this.robots = await api.robots();
    } catch {
      return;
    }
    const chosen = new Set([...this.robotBox.querySelectorAll("input:checked")].map((i) => i.value));
    this.robotBox.replaceChildren(
      ...this.robots.map((r) =>
        el("label", { class: "toggle", title: r.ready ? "ready" : (r.not_ready_reasons || []).join(", ") },
          el("input", { type: "checkbox", value: r.id, checked: chosen.has(r.id), "data-testid": `mission-robot-${r.id}` }),
          ` ${r.id}${r.ready ? "" : ` (not ready: ${(r.not_ready_reasons || []).join(", ") || "unknown"})`} `)),
    );
    this.fillLeader();
  }

  /** The robots picked, in list order. */
  picked() {
    return [...this.robotBox.querySelectorAll("input:checked")].map((i) => i.value);
  }

  /** The leader is one of the robots picked (the first, until another is chosen). */
  fillLeader() {
    const ids = this.picked();
    const keep = ids.includes(this.leader.value) ? this.leader.value : ids[0];
    if (ids.join("\n") !== [...this.leader.options].map((o) => o.value).join("\n")) {
      this.leader.replaceChildren(...ids.map((id) => el("option", { value: id }, id)));
    }
    if (keep) this.leader.value = keep;
  }

  bounds() {
    const xs = this.boundary.map((p) => p[0]);
    const ys = this.boundary.map((p) => p[1]);
    const minx = Math.min(...xs), maxx = Math.max(...xs), miny = Math.min(...ys), maxy = Math.max(...ys);
    const span = Math.max(maxx - minx, maxy - miny) * 1.05;
    return { minx: (minx + maxx - span) / 2, miny: (miny + maxy - span) / 2, span };
  }

  toScreen([x, y]) {
    const b = this.bounds();
    return [((x - b.minx) / b.span) * 100, 100 - ((y - b.miny) / b.span) * 100];
  }

  addCorner(ev) {
    if (this.mission && this.mission.state !== "draft" && !["completed", "aborted", "failed"].includes(this.mission.state)) return;
    const r = this.map.getBoundingClientRect();
    const b = this.bounds();
    const x = b.minx + ((ev.clientX - r.left) / r.width) * b.span;
    const y = b.miny + (1 - (ev.clientY - r.top) / r.height) * b.span;
    this.area.push([Math.round(x * 100) / 100, Math.round(y * 100) / 100]);
    this.draw();
  }

  poly(points, attrs) {
    return svg("polygon", { points: points.map((p) => this.toScreen(p).join(",")).join(" "), ...attrs });
  }

  draw() {
    this.map.setAttribute("viewBox", "0 0 100 100");
    this.map.replaceChildren();
    this.map.append(this.poly(this.boundary, { fill: "none", stroke: "#7fb3d5", "stroke-width": 0.6 }));
    const m = this.mission;
    if (m) {
      for (const part of m.parts) {
        for (const ring of part.polygon) this.map.append(this.poly(ring, { fill: robotColor(part.robot_id, 0.12), stroke: "none" }));
      }
      for (const rings of ringsOf(this.coverage)) {
        const layer = svg("g", { "data-testid": "mission-coverage" });
        for (const ring of rings.slice(0, 1)) layer.append(this.poly(ring, { fill: "rgba(80,220,140,0.45)", stroke: "none" }));
        this.map.append(layer);
      }
      for (const part of m.parts) {
        if (part.path.length < 2) continue;
        this.map.append(svg("polyline", {
          points: part.path.map((p) => this.toScreen(p).join(",")).join(" "),
          fill: "none", stroke: robotColor(part.robot_id), "stroke-width": 0.4, "stroke-dasharray": "1 1",
          "data-testid": "mission-path",
        }));
      }
    }
    if (this.area.length && this.type.value === "formation") {
      this.map.append(svg("polyline", { points: this.area.map((p) => this.toScreen(p).join(",")).join(" "),
        fill: "none", stroke: "#fff", "stroke-width": 0.5, "data-testid": "mission-area" }));
    } else if (this.area.length) {
      this.map.append(this.poly(this.area, { fill: "rgba(255,255,255,0.08)", stroke: "#fff", "stroke-width": 0.4, "data-testid": "mission-area" }));
    }
    for (const r of this.robots) {
      if (!r.position) continue;
      const [cx, cy] = this.toScreen([r.position.x, r.position.y]);
      this.map.append(svg("circle", { cx, cy, r: 1.6, fill: robotColor(r.id) }));
    }
    this.render();
  }

  render() {
    const m = this.mission;
    const can = session.allows("operator");
    const state = m?.state;
    const idle = !m || ["completed", "aborted", "failed"].includes(state);
    this.buttons.plan.disabled = !can || !(idle || state === "draft");
    this.buttons.start.disabled = !can || state !== "draft";
    this.buttons.pause.disabled = !can || state !== "running";
    this.buttons.resume.disabled = !can || state !== "paused";
    this.buttons.abort.disabled = !can || !["draft", "running", "paused"].includes(state);
    this.buttons.pool.disabled = !can;
    const formation = this.type.value === "formation";
    this.coverageRow.hidden = formation;
    this.formationRow.hidden = !formation;
    this.map.setAttribute("aria-label", formation ? "Mission map: click the points of the leader's path"
      : "Mission map: click to add corners of the area");
    if (!m) {
      this.status.textContent = !can ? "Read-only." : formation
        ? "Click the leader's path on the map (two points or more), pick the robots and the leader, preview."
        : "Draw an area (click corners) or take the whole pool, pick robots, preview.";
      return;
    }
    const pct = (m.covered_fraction * 100).toFixed(1);
    const eta = m.eta_s != null ? ` · ETA ${Math.round(m.eta_s)} s` : "";
    const per = m.progress.map((p) => `${p.robot_id} ${p.status} ${(p.fraction * 100).toFixed(0)}%`).join(", ");
    this.status.textContent = `${m.name}: ${state}${m.reason ? ` (${m.reason})` : ""} · covered ${pct}% · ${Math.round(m.elapsed_s)} s${eta} · ${per}`;
    this.status.dataset.state = state;
    this.status.dataset.covered = String(m.covered_fraction);
    this.events.replaceChildren(
      ...(m.events || []).slice(-8).map((e) => el("li", { "data-kind": e.kind }, eventText(e))),
    );
  }

  async act(fn) {
    try {
      await fn();
    } catch (err) {
      this.status.textContent = `Refused: ${err.message}`;
    }
  }

  async create() {
    const robots = this.picked();
    const body = this.type.value === "formation" ? this.formationBody(robots)
      : { type: "coverage", name: "", robots, params: { sweep_width_m: Number(this.width.value), ...(this.area.length >= 3 ? { area: this.area } : {}) } };
    const m = await api.post("/api/missions", body);
    this.area = [];
    await this.follow(m.id);
  }

  /** A formation: the leader follows the clicked path; follower k holds a slot in a V behind it. */
  formationBody(robots) {
    if (this.area.length < 2) throw new Error("click at least two points of the leader's path on the map");
    const leader = this.leader.value || robots[0];
    const d = Number(this.spacing.value);
    const slots = Object.fromEntries(robots.filter((r) => r !== leader).map((r, i) => {
      const rank = Math.floor(i / 2) + 1;
      return [r, [-d * rank, (i % 2 ? -1 : 1) * d * rank]];
    }));
    return { type: "formation", name: "", robots, params: { leader, path: this.area, slots, loop: this.loop.checked } };
  }

  async action(name) {
    if (!this.mission) return;
    this.mission = await api.post(`/api/missions/${this.mission.id}/${name}`, {});
    await this.poll();
  }

  async follow(id) {
    this.mission = await api.get(`/api/missions/${id}`);
    this.coverage = null;
    clearInterval(this.timer);
    this.timer = setInterval(() => this.poll(), POLL_MS);
    await this.poll();
  }

  async poll() {
    if (!this.mission) return;
    try {
      const id = this.mission.id;
      const [m, cov] = await Promise.all([api.get(`/api/missions/${id}`), api.get(`/api/missions/${id}/coverage`)]);
      this.mission = m;
      this.coverage = cov;
      await this.refreshRobots();
      if (["completed", "aborted", "failed"].includes(m.state)) clearInterval(this.timer);
    } catch { /* next poll */ }
    this.draw();
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
