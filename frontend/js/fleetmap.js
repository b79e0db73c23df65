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
import { api } from "./api.js";
import { robotColor } from "./robotcolor.js";
import { normalizeSite, siteSummary, siteTraces } from "./sitedraw.js";
import { store, TRAIL_SECONDS } from "./store.js";
import { baseLayout, onThemeChange, plotConfig, themeColors } from "./theme.js";
import { el } from "./util.js";

const HEADING_M = 0.25;
const BS_AXIS_M = 0.3;
export const TAG_MEMORY_S = 30;
const TRAIL_MAX_ALPHA = 0.55;
const SITE_MARGIN_M = 0.3;
const BS_X_COLOR = "#d9534f";
const BS_Y_COLOR = "#5cb85c";
/** Speed from the newest position and the trail point at least this far back. */
const SPEED_WINDOW_S = 0.5;
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
    this.el.addEventListener("mousemove", (ev) => this.hover(ev));
    this.el.addEventListener("mouseleave", () => (this.tip.hidden = true));
    this.el.addEventListener("click", (ev) => {
      if (this.mapClick(ev, "click")) return;
      const hit = this.pick(ev);
      if (hit) this.onSelect(hit);
    });
    // touch: Plotly's drag layer swallows the click a tap would make, so a short, still tap selects too
    this.el.addEventListener("pointerdown", (ev) => {
      this.tapStart = ev.pointerType === "mouse" ? null : { x: ev.clientX, y: ev.clientY, t: ev.timeStamp };
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
    this.el.addEventListener("dblclick", (ev) => this.mapClick(ev, "dblclick"));
    this.loop = this.loop.bind(this);
    requestAnimationFrame(this.loop);
    // fading trails need redraws even when nothing new arrives
    setInterval(() => (this.moved = true), 250);
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
    const c = this.colors;
    const line = (color, dash) => el("span", { class: `lg-line${dash ? " dotted" : ""}`, style: `border-color:${color}` });
    const mark = (cls, color) => el("span", { class: `lg-mark ${cls}`, style: `background:${color}` });
    const item = (swatch, text) => el("span", { class: "lg-item" }, swatch, text);
    this.legend.replaceChildren(
      item(line(BS_X_COLOR), "base station x axis"), item(line(BS_Y_COLOR), "y axis"),
      item(mark("square", c.muted), "base station"), item(mark("diamond", c.warn), `AprilTag seen (${TAG_MEMORY_S} s)`),
      el("span", { class: `lg-item${this.site ? "" : " site-none"}`, "data-testid": "site-status",
        title: siteSummary(this.site, this.siteError) }, this.site ? line(c.muted, true) : "⚠",
      this.site ? "pool outline" : siteSummary(this.site, this.siteError)),
      this.site?.keepouts.length ? item(mark("square", c.bad), "keep-out") : "",
      this.site?.tags.length ? item(el("span", { class: "lg-mark square-open" }), "wall tag (site)") : "",
      item(el("span", { class: "lg-mark round" }), "robot, its own colour; ring: red e-stop, amber stale; grey: offline; ! open alarm"),
      item(el("span", { class: "lg-trail" }), `trail ${TRAIL_SECONDS} s`),
    );
  }

  /** The selected robot's pose and speed, a few times a second. */
  renderReadout() {
    const robot = this.selected ? this.source.robots.get(this.selected) : null;
    const p = robot?.position;
    if (!robot || !p) {
      this.readout.textContent = this.selected ? `${this.selected}: no position yet` : "Select a robot for its pose and speed.";
      delete this.readout.dataset.robot;
      return;
    }
    const speed = this.speed(this.selected, p);
    const yaw = p.yaw != null && Number.isFinite(p.yaw) ? `${((p.yaw * 180) / Math.PI).toFixed(1)}°` : "—";
    this.readout.dataset.robot = this.selected;
    this.readout.replaceChildren(
      el("span", { class: "robot-dot", style: `background:${robotColor(this.selected)}` }),
      el("strong", {}, this.selected),
      ` x ${p.x.toFixed(3)} m · y ${p.y.toFixed(3)} m · z ${(p.z ?? 0).toFixed(3)} m · yaw ${yaw} · `,
      el("span", { dataset: { testid: "map-readout-speed" } }, speed == null ? "speed —" : `speed ${speed.toFixed(2)} m/s`),
      robot.online ? "" : el("span", { class: "muted" }, " · offline: last known pose"),
    );
  }

  /** Ground speed (m/s) from the newest position and the trail point SPEED_WINDOW_S or more before it. */
  speed(id, p) {
    const trail = this.source.trails.get(id) ?? [];
    for (let i = trail.length - 1; i >= 0; i--) {
      const dt = p.ts - trail[i].t;
      if (dt >= SPEED_WINDOW_S) return Math.hypot(p.x - trail[i].x, p.y - trail[i].y) / dt;
    }
    return null;
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

  /** The Plotly traces: base stations as axis frames (the seed's plot_bs_pose) and the tags seen. */
  staticTraces() {
    const c = this.colors;
    const now = this.source.now();
    const bsX = { x: [], y: [] }, bsY = { x: [], y: [] }, bsP = { x: [], y: [], text: [] };
    const seen = new Set();
    for (const geo of this.source.geometry.values()) {
      for (const bs of geo.base_stations ?? []) {
        if (seen.has(bs.id)) continue;
        seen.add(bs.id);
        const [px, py] = bs.position;
        const r = bs.rotation; // columns are the station's axes in the Lighthouse frame
        bsX.x.push(px, px + BS_AXIS_M * r[0][0], null);
        bsX.y.push(py, py + BS_AXIS_M * r[1][0], null);
        bsY.x.push(px, px + BS_AXIS_M * r[0][1], null);
        bsY.y.push(py, py + BS_AXIS_M * r[1][1], null);
        bsP.x.push(px);
        bsP.y.push(py);
        bsP.text.push(`BS ${bs.id}`);
      }
    }
    const tags = { x: [], y: [], text: [] };
    for (const [id, t] of this.tags) {
      if (now - t.t > TAG_MEMORY_S) {
        this.tags.delete(id);
        continue;
      }
      tags.x.push(t.x);
      tags.y.push(t.y);
      tags.text.push(`tag ${id}`);
    }
    return [
      ...siteTraces(this.site, c),
      { type: "scattergl", mode: "lines", name: "bs-x", x: bsX.x, y: bsX.y, hoverinfo: "skip", line: { color: BS_X_COLOR, width: 2 } },
      { type: "scattergl", mode: "lines", name: "bs-y", x: bsY.x, y: bsY.y, hoverinfo: "skip", line: { color: BS_Y_COLOR, width: 2 } },
      { type: "scattergl", mode: "markers+text", name: "base stations", x: bsP.x, y: bsP.y, text: bsP.text,
        textposition: "bottom center", textfont: { color: c.muted, size: 10 }, hoverinfo: "text",
        marker: { size: 9, symbol: "square", color: c.muted } },
      { type: "scattergl", mode: "markers+text", name: "tags", x: tags.x, y: tags.y, text: tags.text,
        textposition: "bottom center", textfont: { color: c.warn, size: 10 }, hoverinfo: "text",
        marker: { size: 9, symbol: "diamond", color: c.warn } },
    ];
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

  /** Lighthouse metres -> CSS pixels in the map element, from the axes Plotly laid out. */
  projection() {
    const fl = this.el._fullLayout;
    const xa = fl?.xaxis, ya = fl?.yaxis;
    if (!xa?._length || !ya?._length) return null;
    const [x0, x1] = this.liveRanges?.x ?? xa.range;
    const [y0, y1] = this.liveRanges?.y ?? ya.range;
    const kx = xa._length / (x1 - x0), ky = ya._length / (y1 - y0);
    return {
      px: (x) => xa._offset + (x - x0) * kx,
      py: (y) => ya._offset + (y1 - y) * ky,
      x: (px) => x0 + (px - xa._offset) / kx,
      y: (py) => y1 - (py - ya._offset) / ky,
      clip: [xa._offset, ya._offset, xa._length, ya._length],
    };
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
    for (const underlay of this.underlays) underlay.draw(ctx, proj);
    // trails first (under the robots): one small square per kept point in the robot's colour, fading with age
    const { robots, trails } = this.source;
    for (const [id] of robots) {
      const pts = trails.get(id);
      if (!pts?.length) continue;
      ctx.fillStyle = robotColor(id);
      const latest = pts[pts.length - 1].t;
      for (const p of pts) {
        ctx.globalAlpha = TRAIL_MAX_ALPHA * Math.max(0.05, 1 - (latest - p.t) / TRAIL_SECONDS);
        ctx.fillRect(px(p.x) - 1.5, py(p.y) - 1.5, 3, 3);
      }
    }
    ctx.globalAlpha = 1;
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
      this.drawRobot(ctx, proj, id, robot, x, y, false);
    }
    if (selectedAt) this.drawRobot(ctx, proj, ...selectedAt, true);
    for (const overlay of this.overlays) overlay.draw(ctx, proj);
    ctx.restore();
  }

  /** Heading line, marker (the robot's colour; its state as a ring) and the label on the side away from
   * the heading, so the line never runs through the name. */
  drawRobot(ctx, proj, id, robot, x, y, selected) {
    const c = this.colors;
    const pos = robot.position;
    const r = selected ? 8.5 : 6;
    let heading = null;
    let ux = 0, uy = -1; // pixel direction of the heading (default: labels go below)
    if (pos.yaw != null && Number.isFinite(pos.yaw)) {
      const hx = proj.px(pos.x + HEADING_M * Math.cos(pos.yaw)), hy = proj.py(pos.y + HEADING_M * Math.sin(pos.yaw));
      const len = Math.hypot(hx - x, hy - y);
      if (len > 0) [ux, uy] = [(hx - x) / len, (hy - y) / len];
      heading = [x, y, hx, hy];
      ctx.strokeStyle = c.fg;
      ctx.lineWidth = 2;
      ctx.beginPath();
      ctx.moveTo(x, y);
      ctx.lineTo(hx, hy);
      ctx.stroke();
    }
    const stale = this.source.isStale(robot);
    ctx.fillStyle = robot.online ? robotColor(id) : c.offline;
    ctx.strokeStyle = robot.online ? c.fg : robotColor(id);
    ctx.lineWidth = selected ? 3 : robot.online ? 1 : 2;
    ctx.beginPath();
    ctx.arc(x, y, r, 0, 2 * Math.PI);
    ctx.fill();
    ctx.stroke();
    if (robot.online && (robot.estop || stale)) {
      ctx.strokeStyle = robot.estop ? c.bad : c.warn;
      ctx.lineWidth = 2.5;
      ctx.setLineDash(robot.estop ? [] : [3, 2]);
      ctx.beginPath();
      ctx.arc(x, y, r + 3.5, 0, 2 * Math.PI);
      ctx.stroke();
      ctx.setLineDash([]);
    }
    const alarms = Object.values(robot.alarms ?? {});
    if (alarms.length) { // an open alarm: a "!" badge beside the marker (red when critical)
      ctx.fillStyle = alarms.includes("critical") ? c.bad : c.warn;
      ctx.beginPath();
      ctx.arc(x + r + 4, y - r - 4, 6, 0, 2 * Math.PI);
      ctx.fill();
      ctx.fillStyle = "#fff";
      ctx.textBaseline = "middle";
      ctx.fillText("!", x + r + 4, y - r - 4); // (labels are drawn centred: textAlign stays as it is)
    }
    // the label's centre sits opposite the heading, far enough that its box clears the marker and the line
    const w = ctx.measureText(id).width, h = 12;
    const d = r + 5 + Math.abs(ux) * w / 2 + Math.abs(uy) * h / 2;
    const lx = x - ux * d, ly = y - uy * d;
    ctx.textBaseline = "middle";
    ctx.fillStyle = c.fg;
    ctx.fillText(id, lx, ly);
    this.labels.set(id, { x: lx - w / 2, y: ly - h / 2, w, h, heading });
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

/** Axis ranges from a plotly_relayouting event (a drag in progress), keeping what it does not say. */
function rangesFrom(ev, prev) {
  const pick = (ax) => {
    if (ev[`${ax}.range[0]`] !== undefined) return [ev[`${ax}.range[0]`], ev[`${ax}.range[1]`]];
    if (Array.isArray(ev[`${ax}.range`])) return ev[`${ax}.range`];
    return prev?.[ax] ?? null;
  };
  return { x: pick("xaxis"), y: pick("yaxis") };
}
