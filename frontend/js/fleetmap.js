// The pool map. Two layers in the same Lighthouse frame (metres, equal axes):
// - a Plotly figure for what changes rarely: axes, grid, zoom/pan, the pool outline, the base stations
//   (one WebGL trace per kind: x axes, y axes, centres) and the AprilTags seen (one trace). It is
//   redrawn only when those change (at most twice a second), never per telemetry message;
// - a 2-D canvas over the plot area for what moves at 20 Hz: every robot's fading trail, marker,
//   heading and label, all robots in one pass, at most once per animation frame.
// Why the split: a Plotly.react of the map costs 12-18 ms of script plus a WebGL read-back on machines
// without GPU compositing (50-80 ms frames at 20 Hz x 100 robots, measured in bench/bench_dashboard.py);
// the canvas pass for 100 robots costs under 2 ms, so the page stays at 60 fps.
import { store, TRAIL_SECONDS } from "./store.js";
import { baseLayout, onThemeChange, plotConfig, themeColors } from "./theme.js";

const HEADING_M = 0.25;
const BS_AXIS_M = 0.3;
const TAG_MEMORY_S = 30;
const TRAIL_RGB = "79,150,170";
const TRAIL_MAX_ALPHA = 0.55;
// the Plotly layer: base stations and tags change rarely; tags move with every detection, so cap it
const MAX_STATIC_REDRAW_HZ = 2;
const PICK_RADIUS_PX = 14;

export class FleetMap {
  constructor(el, { onSelect, debug }) {
    this.el = el;
    this.onSelect = onSelect;
    this.debug = debug;
    this.selected = null;
    this.dirty = true; // the canvas layer
    this.staticDirty = true; // the Plotly layer
    this.ready = false;
    this.tags = new Map(); // tag id -> {x, y, t}
    this.drawn = new Map(); // robot id -> {x, y, px, py} as last drawn (picking, hover, tests)
    this.liveRanges = null; // axis ranges while the user drags (plotly_relayouting)
    this.el.style.position = "relative";
    this.canvas = document.createElement("canvas");
    this.canvas.className = "map-live";
    this.canvas.dataset.testid = "map-live";
    this.canvas.style.cssText = "position:absolute;left:0;top:0;pointer-events:none;z-index:2";
    this.tip = document.createElement("div");
    this.tip.className = "map-tip";
    this.tip.hidden = true;
    this.applyTheme();
    onThemeChange(() => {
      this.applyTheme();
      this.staticDirty = this.dirty = true;
    });
    store.on("telemetry", (msg) => {
      if (msg.stream === "position") this.dirty = true;
      else if (msg.stream === "apriltag") this.noteTags(msg);
    });
    store.on("robots", () => (this.dirty = true));
    store.on("geometry", () => (this.staticDirty = true));
    // the panel changes size without a window resize too (the e-stop bar, the list growing)
    new ResizeObserver(() => {
      if (this.ready && this.el.offsetParent !== null) Plotly.Plots.resize(this.el);
      this.dirty = true;
    }).observe(this.el);
    this.el.addEventListener("mousemove", (ev) => this.hover(ev));
    this.el.addEventListener("mouseleave", () => (this.tip.hidden = true));
    this.el.addEventListener("click", (ev) => {
      const hit = this.pick(ev);
      if (hit) this.onSelect(hit);
    });
    this.loop = this.loop.bind(this);
    requestAnimationFrame(this.loop);
    // fading trails need redraws even when nothing new arrives
    setInterval(() => (this.dirty = true), 250);
  }

  applyTheme() {
    this.colors = themeColors();
    this.layout = baseLayout({
      uirevision: "keep", // user zoom survives updates
      margin: { l: 40, r: 8, t: 8, b: 30 },
      hovermode: "closest",
      xaxis: { range: [-2.3, 2.3], gridcolor: this.colors.grid, zerolinecolor: this.colors.grid, title: { text: "x (m)" } },
      yaxis: { range: [-2.3, 2.3], scaleanchor: "x", scaleratio: 1, gridcolor: this.colors.grid,
        zerolinecolor: this.colors.grid, title: { text: "y (m)" } },
      shapes: [{ type: "rect", x0: -2, y0: -2, x1: 2, y1: 2, line: { color: this.colors.grid, width: 2, dash: "dot" } }],
    });
  }

  select(id) {
    this.selected = id;
    this.dirty = true;
  }

  noteTags(msg) {
    const pose = store.robots.get(msg.robot_id)?.position;
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
    const now = Date.now() / 1000;
    const bsX = { x: [], y: [] }, bsY = { x: [], y: [] }, bsP = { x: [], y: [], text: [] };
    const seen = new Set();
    for (const geo of store.geometry.values()) {
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
      { type: "scattergl", mode: "lines", name: "bs-x", x: bsX.x, y: bsX.y, hoverinfo: "skip", line: { color: "#d9534f", width: 2 } },
      { type: "scattergl", mode: "lines", name: "bs-y", x: bsY.x, y: bsY.y, hoverinfo: "skip", line: { color: "#5cb85c", width: 2 } },
      { type: "scattergl", mode: "markers+text", name: "base stations", x: bsP.x, y: bsP.y, text: bsP.text,
        textposition: "bottom center", textfont: { color: c.muted, size: 10 }, hoverinfo: "text",
        marker: { size: 9, symbol: "square", color: c.muted } },
      { type: "scattergl", mode: "markers+text", name: "tags", x: tags.x, y: tags.y, text: tags.text,
        textposition: "bottom center", textfont: { color: c.warn, size: 10 }, hoverinfo: "text",
        marker: { size: 9, symbol: "diamond", color: c.warn } },
    ];
  }

  renderStatic() {
    Plotly.react(this.el, this.staticTraces(), this.layout, plotConfig);
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
    // trails first (under the robots): one small square per kept point, fading with age
    ctx.fillStyle = `rgb(${TRAIL_RGB})`;
    for (const [id] of store.robots) {
      const pts = store.trails.get(id);
      if (!pts?.length) continue;
      const latest = pts[pts.length - 1].t;
      for (const p of pts) {
        ctx.globalAlpha = TRAIL_MAX_ALPHA * Math.max(0.05, 1 - (latest - p.t) / TRAIL_SECONDS);
        ctx.fillRect(px(p.x) - 1.5, py(p.y) - 1.5, 3, 3);
      }
    }
    ctx.globalAlpha = 1;
    this.drawn.clear();
    ctx.font = "11px system-ui, sans-serif";
    ctx.textAlign = "center";
    ctx.textBaseline = "bottom";
    let selectedAt = null;
    for (const [id, robot] of store.robots) {
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
    ctx.restore();
  }

  drawRobot(ctx, proj, id, robot, x, y, selected) {
    const c = this.colors;
    const pos = robot.position;
    if (pos.yaw != null && Number.isFinite(pos.yaw)) {
      ctx.strokeStyle = c.fg;
      ctx.lineWidth = 2;
      ctx.beginPath();
      ctx.moveTo(x, y);
      ctx.lineTo(proj.px(pos.x + HEADING_M * Math.cos(pos.yaw)), proj.py(pos.y + HEADING_M * Math.sin(pos.yaw)));
      ctx.stroke();
    }
    const stale = store.isStale(robot);
    ctx.fillStyle = !robot.online ? c.offline : robot.estop ? c.bad : stale ? c.warn : c.accent;
    ctx.strokeStyle = c.fg;
    ctx.lineWidth = selected ? 3 : 1;
    ctx.beginPath();
    ctx.arc(x, y, selected ? 8.5 : 6, 0, 2 * Math.PI);
    ctx.fill();
    ctx.stroke();
    ctx.fillStyle = c.fg;
    ctx.fillText(id, x, y - (selected ? 11 : 8));
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
    if (!window.Plotly || this.el.offsetParent === null) return;
    if (this.staticDirty && t0 - (this.lastStatic ?? -1e9) >= 1000 / MAX_STATIC_REDRAW_HZ) {
      this.lastStatic = t0;
      this.staticDirty = false;
      this.renderStatic();
    }
    if (!this.dirty || !this.ready) return;
    this.dirty = false;
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
