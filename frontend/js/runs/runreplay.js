// Replay of a run on its page, with the live components on one timeline: the fleet map (FleetMap: trails,
// the site version the run recorded, base stations, tags seen, the robots' goals and the coverage their
// missions swept), the camera (CameraView: the stored frame at the replay time with its AprilTag overlay),
// the command log (CommandLog) and the events with the markers (EventsPanel). They read a ReplayCursor
// (replaycursor.js) instead of the live store; only this file knows it is a replay.
// Controls: play / pause, speeds 0.25x to 8x, a scrubber, markers on the timeline, "export this range" (a
// selection set at the replay time), and a second run drawn dashed on the same map for comparison.
import { focusableScrollRegions } from "../core/a11y.js";
import { api } from "../core/api.js";
import { CameraView } from "../robot/camera.js";
import { CommandLog } from "../drive/commandlog.js";
import { EventsPanel } from "../fleet/events.js";
import { FleetMap } from "../map/fleetmap.js";
import { drawGoal, fromMotion } from "../drive/goto.js";
import { ReplayCameraFeed } from "./replaycamera.js";
import { loadStream, ReplayCursor, lastAtOrBefore } from "./replaycursor.js";
import { robotColor } from "../core/robotcolor.js";
import { normalizeSite } from "../map/sitedraw.js";
import { themeColors } from "../core/theme.js";
import { el } from "../core/util.js";

const SPEEDS = [0.25, 0.5, 1, 2, 4, 8];
const STEPS = 1000;
const TICK_MS = 50;
const COVERAGE_FILL = "rgba(80, 220, 140, 0.35)";
/** Missions looked at for a run's coverage (the newest of the run's robots, overlapping it in time). */
const MISSIONS_LOOKED_AT = 10;

function secs(s) {
  return `${s.toFixed(1)} s`;
}

/** The site as the run recorded it (its version), or null when that version had none. */
async function siteOf(run) {
  const [v] = await api.get(`/api/site/versions?before=${run.site_version + 1}&limit=1`);
  return v && v.version === run.site_version ? normalizeSite(v) : null;
}

/** The missions of the run's robots that ran during it: their running windows and sweep widths. */
async function missionsOf(run, end) {
  const mine = new Set(run.robots);
  const listed = (await api.get("/api/missions").catch(() => []))
    .filter((m) => m.robots.some((r) => mine.has(r)) && m.created_at <= end).slice(0, MISSIONS_LOOKED_AT);
  const full = await Promise.all(listed.map((m) => api.get(`/api/missions/${encodeURIComponent(m.id)}`).catch(() => null)));
  return full.filter((m) => m && m.started_at != null && m.started_at <= end && (m.ended_at ?? Infinity) >= run.started_at)
    .map((m) => ({ id: m.id, name: m.name, robots: m.robots, from: m.started_at, to: m.ended_at ?? Infinity,
      width: Number(m.params?.sweep_width_m) || 0.2 }));
}

export class RunReplay {
  /** onExportRange(from, to, format): download that stretch; onError(err): show a failure. */
  constructor({ onExportRange = () => {}, onError = () => {} } = {}) {
    this.cursor = new ReplayCursor();
    this.onExportRange = onExportRange;
    this.onError = onError;
    this.t = 0;
    this.timer = null;
    this.other = null; // { run, tracks } of the run compared with
    this.missions = [];
    // the map: the live FleetMap on the replay's data
    this.mapEl = el("div", { class: "map replay-map", "data-testid": "replay-map" });
    const mapBox = el("section", { class: "replay-map-box", "aria-label": "Replay map" }, this.mapEl);
    this.legend = el("ul", { class: "replay-legend", "data-testid": "replay-legend", "aria-label": "Runs on the map" });
    // the camera: the live CameraView on the run's stored frames
    this.cameraRobot = el("select", { "aria-label": "Camera of robot", "data-testid": "replay-camera-robot" });
    this.cameraRobot.addEventListener("change", () => this.showCamera(this.cameraRobot.value));
    const overlayToggle = el("input", { type: "checkbox", checked: true, "data-testid": "replay-overlay-toggle" });
    const cameraInfo = el("span", { class: "muted", "data-testid": "replay-camera-info" }, "no frames");
    const cameraCanvas = el("canvas", { width: 640, height: 480, "data-testid": "replay-camera-canvas" });
    const overlayCanvas = el("canvas", { width: 640, height: 480, "data-testid": "replay-overlay-canvas" });
    this.feed = new ReplayCameraFeed();
    this.camera = new CameraView({ canvas: cameraCanvas, overlay: overlayCanvas, info: cameraInfo, toggle: overlayToggle, feed: this.feed });
    const cameraBox = el("section", { class: "replay-camera", "aria-label": "Replay camera" },
      el("div", { class: "panel-head" }, el("h4", {}, "Camera"), this.cameraRobot,
        el("label", { class: "toggle" }, overlayToggle, " AprilTag overlay"), cameraInfo),
      el("div", { class: "camera-box" }, cameraCanvas, overlayCanvas));
    // the command log and the events (markers among them) up to the replay time
    const logHost = el("div", { class: "replay-log" });
    const eventsHost = el("div", { class: "replay-events" });
    this.log = new CommandLog(logHost, { source: this.cursor, testid: "replay-command-log" });
    this.events = new EventsPanel(eventsHost, { source: this.cursor, testid: "replay-events" });
    // the controls
    this.play = el("button", { type: "button", class: "btn", "data-testid": "replay-play" }, "Play");
    this.speed = el("select", { "aria-label": "Replay speed", "data-testid": "replay-speed" },
      ...SPEEDS.map((s) => el("option", { value: s, selected: s === 1 }, `${s}×`)));
    this.scrub = el("input", { type: "range", min: 0, max: STEPS, value: 0, step: 1, "aria-label": "Replay time", "data-testid": "replay-scrubber" });
    this.label = el("span", { class: "muted", "data-testid": "replay-time" }, "");
    this.ticks = el("div", { class: "replay-markers", "data-testid": "replay-markers" });
    this.rangeLabel = el("span", { class: "muted", role: "status", "data-testid": "replay-range" }, "");
    this.exportFormat = el("select", { "aria-label": "Format of the range export", "data-testid": "replay-export-format" },
      el("option", { value: "mcap" }, "MCAP"), el("option", { value: "parquet" }, "Parquet"), el("option", { value: "zip" }, "zip"));
    const rangeBox = el("div", { class: "replay-controls", "data-testid": "replay-range-controls" },
      el("button", { type: "button", class: "btn small", "data-testid": "replay-range-from", title: "The selection starts at the replay time", onclick: () => this.setRange(this.t, null) }, "Range start here"),
      el("button", { type: "button", class: "btn small", "data-testid": "replay-range-to", title: "The selection ends at the replay time", onclick: () => this.setRange(null, this.t) }, "Range end here"),
      el("button", { type: "button", class: "btn small", "data-testid": "replay-range-all", onclick: () => this.setRange(this.start_, this.end) }, "Whole run"),
      this.rangeLabel, this.exportFormat,
      el("button", { type: "button", class: "btn", "data-testid": "replay-export-range", onclick: () => this.exportRange() }, "Export this range"));
    this.compareSelect = el("select", { "aria-label": "Compare with another run", "data-testid": "replay-compare" },
      el("option", { value: "" }, "— none —"));
    this.compareSelect.addEventListener("change", () => this.compareWith(this.compareSelect.value).catch((err) => this.onError(err)));
    this.host = el("section", { class: "replay", "data-testid": "replay" },
      el("h3", {}, "Replay"),
      el("div", { class: "replay-controls" }, this.play, this.speed, this.scrub, this.label), this.ticks,
      el("div", { class: "replay-grid" },
        el("div", { class: "replay-map-col" }, mapBox, this.legend),
        el("div", { class: "replay-side" }, cameraBox, logHost, eventsHost)),
      rangeBox,
      el("div", { class: "replay-controls" }, el("label", {}, "Compare with run ", this.compareSelect)));
    focusableScrollRegions(this.host);
    this.map = new FleetMap(this.mapEl, { source: this.cursor, fetchSite: false, onSelect: (id) => this.select(id) });
    this.map.addLayer({ id: "goals", label: "goals", draw: (ctx, proj) => this.drawGoals(ctx, proj) }, { over: true });
    this.map.addLayer({ id: "compare", label: "compared run", draw: (ctx, proj) => this.drawCompare(ctx, proj) },
      { over: true });
    this.map.addLayer({ id: "coverage", label: "swept by missions", draw: (ctx, proj) => this.drawCoverage(ctx, proj) });
    this.play.addEventListener("click", () => (this.timer ? this.pause() : this.start()));
    this.scrub.addEventListener("input", () => this.seek(this.start_ + (Number(this.scrub.value) / STEPS) * this.span()));
  }

  span() {
    return Math.max(1e-3, this.end - this.start_);
  }

  async load(run) {
    this.pause();
    this.run = run;
    this.start_ = run.started_at;
    this.end = run.ended_at ?? Date.now() / 1000;
    this.range = [this.start_, this.end];
    this.other = null;
    this.feed.runId = run.id;
    const [site, runs, missions] = await Promise.all([
      siteOf(run).then((s) => [s, ""], (err) => [null, err.message]),
      api.get("/api/runs?running=false&limit=100").catch(() => []),
      missionsOf(run, this.end),
      this.cursor.load(run),
    ]);
    this.map.setSite(...site);
    this.missions = missions;
    this.compareSelect.replaceChildren(el("option", { value: "" }, "— none —"),
      ...runs.filter((r) => r.id !== run.id).map((r) => el("option", { value: r.id }, `${r.id}: ${r.name}`)));
    this.cameraRobot.replaceChildren(...run.robots.map((id) => el("option", { value: id }, id)));
    this.showRange();
    this.drawLegend();
    this.ticks.replaceChildren(...run.markers.map((m) => el("button", {
      type: "button", class: "btn small", title: m.text, "data-testid": "replay-marker",
      onclick: () => this.seek(m.ts),
    }, `${(m.ts - this.start_).toFixed(1)} s ${m.text}`)));
    this.seek(this.start_);
    this.select(run.robots[0] ?? null);
  }

  /** A robot chosen on the map: its readout, and its camera. */
  select(id) {
    this.map.select(id);
    if (id && id !== this.camera.robotId) {
      this.cameraRobot.value = id;
      this.showCamera(id);
    }
  }

  showCamera(id) {
    this.camera.open(id);
  }

  // -- the selection ("export this range") ------------------------------------------------------------------
  setRange(from, to) {
    let [lo, hi] = this.range;
    if (from != null) lo = from;
    if (to != null) hi = to;
    if (lo > hi) [lo, hi] = from != null ? [lo, Math.max(lo, this.end)] : [Math.min(hi, this.start_), hi];
    this.range = [Math.max(this.start_, lo), Math.min(this.end, hi)];
    this.showRange();
  }

  showRange() {
    const [lo, hi] = this.range;
    this.rangeLabel.textContent = `Selection ${secs(lo - this.start_)} – ${secs(hi - this.start_)}`;
    this.rangeLabel.dataset.from = String(lo);
    this.rangeLabel.dataset.to = String(hi);
    const a = ((lo - this.start_) / this.span()) * 100;
    const b = ((hi - this.start_) / this.span()) * 100;
    this.scrub.style.background = `linear-gradient(to right, transparent ${a}%, var(--accent, #2a7de1) ${a}%, var(--accent, #2a7de1) ${b}%, transparent ${b}%)`;
  }

  exportRange() {
    const [lo, hi] = this.range;
    if (!(hi > lo)) {
      this.onError(new Error("the selection is empty: set its start before its end"));
      return;
    }
    this.onExportRange(lo, hi, this.exportFormat.value);
  }

  // -- a second run on the same map ---------------------------------------------------------------------------
  async compareWith(runId) {
    if (!runId) {
      this.other = null;
    } else {
      const run = await api.get(`/api/runs/${runId}`);
      const end = run.ended_at ?? Date.now() / 1000;
      this.other = { run, tracks: await loadStream(run.robots, "position", run.started_at, end, (d) => Number.isFinite(d.x)) };
    }
    this.drawLegend();
    this.showState();
    this.map.dirty = true;
  }

  drawLegend() {
    const item = (id, dashed, text) => {
      const swatch = el("canvas", { width: 28, height: 8, "aria-hidden": "true" });
      const g = swatch.getContext("2d");
      g.strokeStyle = robotColor(id);
      g.lineWidth = 2;
      g.setLineDash(dashed ? [5, 3] : []);
      g.beginPath();
      g.moveTo(0, 4);
      g.lineTo(28, 4);
      g.stroke();
      return el("li", { "data-run": dashed ? "compare" : "this" }, swatch, ` ${text}`);
    };
    const items = this.run.robots.map((id) => item(id, false, `${id} — run ${this.run.id} (trail and marker)`));
    if (this.other) {
      items.push(...[...this.other.tracks.keys()].map((id) => item(id, true, `${id} — run ${this.other.run.id}: ${this.other.run.name} (dashed)`)));
    }
    items.push(el("li", { "data-testid": "replay-coverage-legend" }, this.missions.length
      ? `coverage: ${this.missions.map((m) => `${m.name || m.id} (${m.width} m sweep)`).join(", ")}`
      : "coverage: no mission ran during this run"));
    this.legend.replaceChildren(...items);
  }

  // -- the layers a replay adds to the map ----------------------------------------------------------------------
  /** Each robot's running goal at the replay time (its motion report), as Go-to draws it live. */
  drawGoals(ctx, proj) {
    const fg = themeColors().fg;
    const goals = {};
    for (const [id, robot] of this.cursor.robots) {
      const d = this.cursor.motionAt(id);
      if (!d) continue;
      const goal = fromMotion(id, d);
      const at = robot.position ? [robot.position.x, robot.position.y] : null;
      drawGoal(ctx, proj, goal, at, robotColor(id), fg);
      goals[id] = { x: goal.x, y: goal.y, mode: goal.mode };
    }
    this.mapEl.dataset.goals = JSON.stringify(goals);
  }

  /** What the run's missions swept up to the replay time: each robot's track while its mission ran, as
   * wide as the mission's sweep (what the server's coverage is made of). */
  drawCoverage(ctx, proj) {
    let drawn = 0;
    for (const m of this.missions) {
      const w = Math.abs(proj.px(m.width) - proj.px(0));
      for (const id of m.robots) {
        const pts = this.cursor.trackBetween(id, m.from, Math.min(this.t, m.to));
        if (pts.length < 2) continue;
        ctx.save();
        ctx.strokeStyle = COVERAGE_FILL;
        ctx.lineWidth = Math.max(1, w);
        ctx.lineCap = ctx.lineJoin = "round";
        ctx.beginPath();
        pts.forEach((p, i) => (i ? ctx.lineTo(proj.px(p.data.x), proj.py(p.data.y)) : ctx.moveTo(proj.px(p.data.x), proj.py(p.data.y))));
        ctx.stroke();
        ctx.restore();
        drawn += pts.length;
      }
    }
    this.mapEl.dataset.coveragePoints = String(drawn);
  }

  /** The compared run at the same time since its own start: its tracks dashed, its robots as rings. */
  drawCompare(ctx, proj) {
    if (!this.other) return;
    const t = this.other.run.started_at + (this.t - this.start_);
    for (const [id, pts] of this.other.tracks) {
      const k = lastAtOrBefore(pts, t);
      if (k < 0) continue;
      ctx.save();
      ctx.strokeStyle = robotColor(id, 0.9);
      ctx.lineWidth = 2;
      ctx.setLineDash([6, 4]);
      ctx.beginPath();
      for (let i = 0; i <= k; i++) {
        const p = pts[i].data;
        if (i) ctx.lineTo(proj.px(p.x), proj.py(p.y));
        else ctx.moveTo(proj.px(p.x), proj.py(p.y));
      }
      ctx.stroke();
      ctx.setLineDash([]);
      ctx.beginPath();
      ctx.arc(proj.px(pts[k].data.x), proj.py(pts[k].data.y), 6, 0, 2 * Math.PI);
      ctx.stroke();
      ctx.restore();
    }
  }

  // -- playing and seeking ----------------------------------------------------------------------------------------
  start() {
    if (this.t >= this.end) this.seek(this.start_);
    this.play.textContent = "Pause";
    let last = performance.now();
    this.timer = setInterval(() => {
      const now = performance.now();
      const t = Math.min(this.end, this.t + ((now - last) / 1000) * Number(this.speed.value));
      last = now;
      this.seek(t);
      if (t >= this.end) this.pause();
    }, TICK_MS);
  }

  pause() {
    clearInterval(this.timer);
    this.timer = null;
    this.play.textContent = "Play";
  }

  /** Show the run at time ts (epoch s): every view follows; resolves when the camera has its frame. */
  seek(ts) {
    this.t = Math.max(this.start_, Math.min(this.end, ts));
    this.scrub.value = String(Math.round(((this.t - this.start_) / this.span()) * STEPS));
    this.label.textContent = `${(this.t - this.start_).toFixed(1)} s / ${this.span().toFixed(1)} s`;
    this.cursor.seek(this.t);
    this.showState();
    return this.feed.show(this.t);
  }

  /** A seek until everything shows it (the bench's measure): the cursor, the camera's frame, and the
   * map's next drawing of its live layer. */
  async seekAndSettle(ts) {
    await this.seek(ts);
    await new Promise((resolve) => requestAnimationFrame(() => setTimeout(resolve, 0)));
  }

  /** What is shown, for tests and assistive technology: each robot's position at the replay time. */
  showState() {
    const shown = {};
    for (const [id, robot] of this.cursor.robots) {
      if (robot.position) shown[id] = { x: robot.position.x, y: robot.position.y, ts: robot.position.ts };
    }
    this.mapEl.dataset.shown = JSON.stringify(shown);
    this.mapEl.dataset.t = String(this.t);
    if (this.other) {
      const t = this.other.run.started_at + (this.t - this.start_);
      const other = {};
      for (const [id, pts] of this.other.tracks) {
        const k = lastAtOrBefore(pts, t);
        if (k >= 0) other[id] = { x: pts[k].data.x, y: pts[k].data.y, ts: pts[k].ts };
      }
      this.mapEl.dataset.compare = JSON.stringify({ run: this.other.run.id, t, shown: other });
    } else {
      delete this.mapEl.dataset.compare;
    }
  }
}
