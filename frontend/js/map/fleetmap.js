// The pool map. Two layers in the same Lighthouse frame (metres, equal axes):
// - a Plotly figure for what changes rarely: axes, grid, zoom/pan, the pool outline, the base stations
//   (one WebGL trace per kind: x axes, y axes, centres) and the AprilTags seen (one trace). It is
//   redrawn only when those change (at most twice a second), never per telemetry message;
// - a 2-D canvas over the plot area for what moves at 20 Hz: every robot's fading trail, marker,
//   heading and label, all robots in one pass: at once for what the user does (a drag, a selection, a
//   resize), and for new positions at most MAX_LIVE_REDRAW_HZ times a second. Positions come at 20 Hz
//   from each robot, each in its own message: redrawn per message, three parked robots kept the page
//   drawing 45 frames a second (a fifth of a core in Chromium without a GPU, a phone's battery).
// Why the split: a Plotly.react of the map costs 12-18 ms of script plus a WebGL read-back on machines
// without GPU compositing (50-80 ms frames at 20 Hz x 100 robots, measured in bench/bench_dashboard.py);
// the canvas pass for 100 robots costs under 2 ms, so the page stays at 60 fps.
// Each robot has its own colour (robotcolor.js, also in the list and the plots); its state is a ring
// (red: e-stop, amber dashed: stale) or a grey fill (offline). The pool outline comes from the server
// (GET /api/site, FLEET_POOL_BOUNDARY), a legend names every mark, and the selected robot gets a readout.
// What it draws comes from a data source: the live store (store.js) by default, or a run's replay cursor
// (replaycursor.js) with the same fields (robots, trails, geometry, isStale, now, on) and topics
// ("robots", "telemetry", "geometry", and "reset" when the replay jumps). Its public API (projection,
// toMap, toClient, overlays, underlays, onMapClick, setSite, select) is the same for both.
// Its parts: stations.js (base stations and tags), robotdraw.js (trails, markers, labels), legend.js (the
// legend and the selected robot's readout); a layer of another domain adds itself as an underlay or overlay
// (missions/missionlayer.js, drive/goto.js, runs/runreplay.js).
import { api } from "../core/api.js";
import { store } from "../core/store.js";
import { baseLayout, onThemeChange, plotConfig, themeColors } from "../core/theme.js";
import { el } from "../core/util.js";
import { drawScaleBar, LayerToggles } from "./layers.js";
import { projectionOf, rangesFrom } from "./projection.js";
import { renderLegend, renderReadout } from "./legend.js";
import { drawRobot, drawTrails } from "./robotdraw.js";
import { safetyLayer } from "./safetylayer.js";
import { normalizeSite, siteTraces } from "./sitedraw.js";
import { stationTraces } from "./stations.js";

export { TAG_MEMORY_S } from "./stations.js";

const SITE_MARGIN_M = 0.3;
const READOUT_HZ = 4;
// the Plotly layer: base stations and tags change rarely; tags move with every detection, so cap it
const MAX_STATIC_REDRAW_HZ = 2;
// the canvas layer, for new positions: the robots' own position rate (20 Hz by default), so each fix is
// drawn at most 50 ms after it arrived however many robots there are
const MAX_LIVE_REDRAW_HZ = 20;
const PICK_RADIUS_PX = 14;
const TAP_MAX_MS = 600;
const TAP_MAX_MOVE_PX = 10;

export class FleetMap {
  /** ``source``: the live store (default) or a replay cursor; ``fetchSite``: false when the caller gives
   * the site (a replay draws the site version its run recorded, with setSite). */
  constructor(mapEl, { onSelect, debug = { frameTimes: [], renders: 0 }, source = store, fetchSite = true }) {
    this.el = mapEl;
    this.onSelect = onSelect;
    this.debug = debug;
    this.source = source;
    this.selected = null;
    this.dirty = true; // the canvas layer, redrawn on the next frame
    this.moved = false; // the canvas layer, for new positions: redrawn at most MAX_LIVE_REDRAW_HZ
    this.staticDirty = true; // the Plotly layer
    this.ready = false;
    this.tags = new Map(); // tag id -> {x, y, t}
    this.drawn = new Map(); // robot id -> {x, y, px, py} as last drawn (picking, hover, tests)
    this.liveRanges = null; // axis ranges while the user drags (plotly_relayouting)
    this.site = undefined; // GET /api/site: undefined while loading, null when there is none (or it failed)
    this.siteError = "";
    this.overlays = new Set(); // {draw(ctx, proj)}: drawn over the robots on the live layer (goto.js)
    this.underlays = new Set(); // {draw(ctx, proj)}: drawn under the trails (a replay's coverage)
    this.onMapClick = null; // (ev, {x, y}, kind: "click" | "tap" | "dblclick") => true when it took the click
    this.editing = null; // the boundary editor while it runs (boundaryedit.js): it holds the map's clicks
    this.labels = new Map(); // robot id -> {x, y, w, h, heading: [x0, y0, x1, y1] | null} as drawn (tests)
    this.el.style.position = "relative";
    this.canvas = document.createElement("canvas");
    this.canvas.className = "map-live";
    this.canvas.dataset.testid = "map-live";
    this.canvas.style.cssText = "position:absolute;left:0;top:0;pointer-events:none;z-index:2";
    this.tip = document.createElement("div");
    this.tip.className = "map-tip";
    this.tip.hidden = true;
    // no live region: it changes four times a second (announcements would never stop)
    this.readout = el("div", { class: "map-readout", "data-testid": "map-readout" });
    this.legend = el("div", { class: "map-legend", "data-testid": "map-legend" });
    this.el.after(this.readout, this.legend);
    this.layers = new LayerToggles(this); // a checkbox per layer, under the legend (layers.js)
    this.safety = safetyLayer(this); // the selected robot's safety distance, when switched on
    this.addLayer(this.safety, { over: true });
    if (fetchSite) {
      api.get("/api/site").then((site) => this.setSite(normalizeSite(site)), (err) => {
        console.warn("no site:", err.message);
        this.siteError = err.message;
        this.setSite(null);
      });
    }
    setInterval(() => this.renderReadout(), 1000 / READOUT_HZ);
    this.applyTheme();
    onThemeChange(() => {
      this.applyTheme();
      this.staticDirty = this.dirty = true;
    });
    source.on("telemetry", (msg) => {
      if (msg.stream === "position") this.moved = true;
      else if (msg.stream === "apriltag") this.noteTags(msg);
    });
    source.on("robots", () => (this.dirty = true));
    source.on("geometry", () => (this.staticDirty = true));
    // a replay jumped: the tags seen are those of the new moment (the cursor sends them again)
    source.on("reset", () => {
      this.tags.clear();
      this.staticDirty = this.dirty = true;
    });
    // the panel changes size without a window resize too (the e-stop bar, the list growing)
    new ResizeObserver(() => {
      if (this.ready && this.el.offsetParent !== null) Plotly.Plots.resize(this.el);
      this.dirty = true;
    }).observe(this.el);
    this.el.addEventListener("mousemove", (ev) => !this.layers.owns(ev) && this.hover(ev));
    this.el.addEventListener("mouseleave", () => (this.tip.hidden = true));
    this.el.addEventListener("click", (ev) => {
      if (this.layers.owns(ev) || this.mapClick(ev, "click")) return;
      const hit = this.pick(ev);
      if (hit) this.onSelect(hit);
    });
    // touch: Plotly's drag layer swallows the click a tap would make, so a short, still tap selects too
    this.el.addEventListener("pointerdown", (ev) => {
      this.tapStart = ev.pointerType === "mouse" || this.layers.owns(ev) ? null : { x: ev.clientX, y: ev.clientY, t: ev.timeStamp };
    }, true);
    this.el.addEventListener("pointerup", (ev) => {
      const s = this.tapStart;
      this.tapStart = null;
      this.lastTap = { x: ev.clientX, y: ev.clientY, ms: s ? ev.timeStamp - s.t : null, target: ev.target.tagName };
      if (!s || ev.timeStamp - s.t > TAP_MAX_MS || Math.hypot(ev.clientX - s.x, ev.clientY - s.y) > TAP_MAX_MOVE_PX) {
        this.lastTap.outcome = "not a tap";
        return;
      }
      if (this.mapClick(ev, "tap")) return void (this.lastTap.outcome = "map click");
      const hit = this.pick(ev);
      this.lastTap.outcome = hit ?? "nothing near";
      if (hit) this.onSelect(hit);
    }, true);
    this.el.addEventListener("dblclick", (ev) => !this.layers.owns(ev) && this.mapClick(ev, "dblclick"));
    this.loop = this.loop.bind(this);
    requestAnimationFrame(this.loop);
    // fading trails need redraws even when nothing new arrives
    setInterval(() => (this.moved = true), 250);
  }

  /** A layer of another room ({id, label, draw(ctx, proj)}, ``off``: unchecked at first; layers.js): under
   * the robots, or over them. */
  addLayer(layer, { over = false } = {}) {
    (over ? this.overlays : this.underlays).add(layer);
    if (layer.off) this.layers.hidden.add(layer.id); // off until switched on
    this.layers.render();
    this.dirty = true;
  }

  setSite(site, error = "") {
    this.site = site;
    this.siteError = error || this.siteError;
    this.applyTheme();
    this.renderLegend();
    this.staticDirty = true;
  }

  /** The axes frame the site outline (with a margin); without a site Plotly fits what there is. */
  applyTheme() {
    this.colors = themeColors();
    const b = this.site?.boundary ?? [];
    const span = (i) => {
      if (b.length < 3) return undefined;
      const v = b.map((p) => p[i]);
      return [Math.min(...v) - SITE_MARGIN_M, Math.max(...v) + SITE_MARGIN_M];
    };
    this.layout = baseLayout({
      uirevision: `site:${this.site?.version ?? "none"}`, // user zoom survives updates (not a new outline)
      margin: { l: 40, r: 8, t: 8, b: 30 },
      hovermode: "closest",
      xaxis: { range: span(0), gridcolor: this.colors.grid, zerolinecolor: this.colors.grid, title: { text: "x (m)" } },
      yaxis: { range: span(1), scaleanchor: "x", scaleratio: 1, gridcolor: this.colors.grid,
        zerolinecolor: this.colors.grid, title: { text: "y (m)" } },
    });
  }

  renderLegend() {
    renderLegend(this.legend, this.colors, this.site, this.siteError);
  }

  /** The selected robot's pose and speed, a few times a second. */
  renderReadout() {
    renderReadout(this.readout, this.source, this.selected);
  }

  select(id) {
    this.selected = id;
    this.dirty = true;
    this.renderReadout();
  }

  noteTags(msg) {
    // the robot's pose when it saw them: a replay knows it at any time, live it is the newest
    const pose = this.source.poseAt?.(msg.robot_id, msg.ts) ?? this.source.robots.get(msg.robot_id)?.position;
    if (!pose || pose.yaw == null) return;
    for (const d of msg.data.detections ?? []) {
      const [xc, , zc] = d.translation_mm.map((v) => v / 1000); // camera: x right, y down, z forward
      const fwd = zc, left = -xc;
      const c = Math.cos(pose.yaw), s = Math.sin(pose.yaw);
      this.tags.set(d.tag_id, { x: pose.x + c * fwd - s * left, y: pose.y + s * fwd + c * left, t: msg.ts });
    }
    this.staticDirty = true;
  }

  /** The Plotly traces: the site, the base stations as axis frames and the tags seen. */
  staticTraces() {
    const shows = (id) => this.layers.shows(id);
    return [...(shows("site") ? siteTraces(this.site, this.colors) : []),
      ...(shows("stations") ? stationTraces(this.source, this.tags, this.colors) : [])];
  }

  /** Go-to takes the map's clicks while armed: Plotly's double click (reset the zoom) would move the map
   * between two quick clicks of a path. */
  setClicksTaken(taken) {
    this.config = taken ? { ...plotConfig, doubleClick: false } : plotConfig;
    this.staticDirty = true;
    this.lastStatic = -1e9;
  }

  renderStatic() {
    Plotly.react(this.el, this.staticTraces(), this.layout, this.config ?? plotConfig);
    if (!this.ready) {
      this.ready = true;
      // Plotly replaces its own children on the first plot: the live layer and tooltip go on top after
      this.el.appendChild(this.canvas);
      this.el.appendChild(this.tip);
      this.layers.attach();
      this.el.on("plotly_relayouting", (ev) => {
        this.liveRanges = rangesFrom(ev, this.liveRanges);
        this.dirty = true;
      });
      this.el.on("plotly_relayout", () => {
        this.liveRanges = null;
        this.dirty = true;
      });
    }
    this.debug.staticRenders = (this.debug.staticRenders ?? 0) + 1;
    this.dirty = true;
  }

  /** Lighthouse metres -> CSS pixels in the map element, from the axes Plotly laid out (projection.js). */
  projection() {
    return projectionOf(this.el, this.liveRanges);
  }

  drawLive() {
    const proj = this.projection();
    if (!proj) return;
    const dpr = window.devicePixelRatio || 1;
    const w = this.el.clientWidth, h = this.el.clientHeight;
    const cv = this.canvas;
    if (cv.width !== Math.round(w * dpr) || cv.height !== Math.round(h * dpr)) {
      cv.width = Math.round(w * dpr);
      cv.height = Math.round(h * dpr);
      cv.style.width = `${w}px`;
      cv.style.height = `${h}px`;
    }
    const ctx = cv.getContext("2d");
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, w, h);
    ctx.save();
    ctx.beginPath();
    ctx.rect(...proj.clip);
    ctx.clip();
    const { px, py } = proj;
    const shows = (id) => this.layers.shows(id);
    for (const underlay of this.underlays) if (shows(underlay.id)) underlay.draw(ctx, proj);
    const robots = shows("robots") ? this.source.robots : new Map();
    if (shows("trails")) drawTrails(ctx, proj, this.source);
    this.drawn.clear();
    this.labels.clear();
    ctx.font = "11px system-ui, sans-serif";
    ctx.textAlign = "center";
    ctx.textBaseline = "bottom";
    let selectedAt = null;
    for (const [id, robot] of robots) {
      const pos = robot.position;
      if (!pos || !Number.isFinite(pos.x) || !Number.isFinite(pos.y)) continue;
      const x = px(pos.x), y = py(pos.y);
      this.drawn.set(id, { x: pos.x, y: pos.y, px: x, py: y });
      if (id === this.selected) {
        selectedAt = [id, robot, x, y];
        continue; // drawn last, on top
      }
      this.labels.set(id, drawRobot(ctx, proj, this.colors, this.source, { id, robot, x, y, selected: false }));
    }
    if (selectedAt) {
      const [id, robot, x, y] = selectedAt;
      this.labels.set(id, drawRobot(ctx, proj, this.colors, this.source, { id, robot, x, y, selected: true }));
    }
    for (const overlay of this.overlays) if (shows(overlay.id)) overlay.draw(ctx, proj);
    this.el.dataset.scaleM = String(drawScaleBar(ctx, proj, this.colors.fg));
    ctx.restore();
  }

  /** A click or tap on the plot area goes to onMapClick (Go-to) first, with its point in metres. While the
   * boundary is edited a click is the editor's: it neither moves nor selects a robot. */
  mapClick(ev, kind) {
    if (this.editing) return true;
    if (!this.onMapClick) return false;
    const at = this.toMap(ev);
    return at !== null && this.onMapClick(ev, at, kind) === true;
  }

  /** The pointer's place in the Lighthouse frame (metres), or null outside the plot area (``clamp``: the
   * nearest point of the plot area instead, for a drag that runs past its edge). */
  toMap(ev, { clamp = false } = {}) {
    const proj = this.projection();
    if (!proj) return null;
    const r = this.el.getBoundingClientRect();
    let mx = ev.clientX - r.left, my = ev.clientY - r.top;
    const [l, t, w, h] = proj.clip;
    if (mx < l || mx > l + w || my < t || my > t + h) {
      if (!clamp) return null;
      mx = Math.min(Math.max(mx, l), l + w);
      my = Math.min(Math.max(my, t), t + h);
    }
    return { x: proj.x(mx), y: proj.y(my) };
  }

  /** Where the point (metres) is on screen: client pixels (tests click there). */
  toClient(x, y) {
    const proj = this.projection();
    if (!proj) return null;
    const r = this.el.getBoundingClientRect();
    return { x: r.left + proj.px(x), y: r.top + proj.py(y) };
  }

  pick(ev) {
    const r = this.el.getBoundingClientRect();
    const mx = ev.clientX - r.left, my = ev.clientY - r.top;
    let best = null, bestD = PICK_RADIUS_PX;
    for (const [id, d] of this.drawn) {
      const dist = Math.hypot(d.px - mx, d.py - my);
      if (dist <= bestD) [best, bestD] = [id, dist];
    }
    return best;
  }

  hover(ev) {
    const id = this.pick(ev);
    this.el.style.cursor = id ? "pointer" : "";
    if (!id) {
      this.tip.hidden = true;
      return;
    }
    const d = this.drawn.get(id);
    this.tip.textContent = `${id} · x ${d.x.toFixed(2)} m · y ${d.y.toFixed(2)} m`;
    this.tip.style.left = `${d.px + 12}px`;
    this.tip.style.top = `${d.py - 28}px`;
    this.tip.hidden = false;
  }

  loop(t0) {
    requestAnimationFrame(this.loop);
    if (!window.Plotly || this.el.offsetParent === null || this.site === undefined) return;
    if (this.staticDirty && t0 - (this.lastStatic ?? -1e9) >= 1000 / MAX_STATIC_REDRAW_HZ) {
      this.lastStatic = t0;
      this.staticDirty = false;
      this.renderStatic();
    }
    if (!this.ready) return;
    // 0.9: frame times jitter, and a frame that comes 0.1 ms early must not wait a whole frame more
    const due = this.moved && t0 - (this.lastLive ?? -1e9) >= 900 / MAX_LIVE_REDRAW_HZ;
    if (!this.dirty && !due) return;
    this.dirty = this.moved = false;
    this.lastLive = t0;
    const start = performance.now();
    this.drawLive();
    this.debug.renders += 1;
    const ft = this.debug.frameTimes;
    ft.push(performance.now() - start);
    if (ft.length > 600) ft.splice(0, ft.length - 600);
  }

  /** What the live layer drew last: {id: {x, y, px, py}} (metres and CSS pixels in the map element). */
  drawnRobots() {
    return Object.fromEntries(this.drawn);
  }

  /** Each label's box and heading segment as last drawn (CSS pixels): {id: {x, y, w, h, heading}}. */
  drawnLabels() {
    return Object.fromEntries(this.labels);
  }
}
