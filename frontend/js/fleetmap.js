// The pool map: every robot on one WebGL plot. One trace per kind (trails, robots, headings, base
// stations, tags), never one per robot, and at most one Plotly.react per animation frame.
import { store, TRAIL_SECONDS } from "./store.js";
import { baseLayout, onThemeChange, plotConfig, themeColors } from "./theme.js";

const HEADING_M = 0.25;
const BS_AXIS_M = 0.3;
const TAG_MEMORY_S = 30;
const TRAIL_COLORSCALE = [[0, "rgba(79,150,170,0)"], [1, "rgba(79,150,170,0.55)"]];
// at most this many map redraws per second: telemetry at 20 Hz needs no more, and each WebGL redraw of
// a 100-robot fleet costs several ms that the rest of the page (and the drive buttons) need
const MAX_REDRAW_HZ = 15;

export class FleetMap {
  constructor(el, { onSelect, debug }) {
    this.el = el;
    this.onSelect = onSelect;
    this.debug = debug;
    this.selected = null;
    this.dirty = true;
    this.ready = false;
    this.tags = new Map(); // tag id -> {x, y, t}
    this.applyTheme();
    onThemeChange(() => {
      this.applyTheme();
      this.dirty = true;
    });
    store.on("telemetry", (msg) => {
      if (msg.stream === "position") this.dirty = true;
      else if (msg.stream === "apriltag") this.noteTags(msg);
    });
    store.on("robots", () => (this.dirty = true));
    store.on("geometry", () => (this.dirty = true));
    // the panel changes size without a window resize too (the e-stop bar, the list growing)
    new ResizeObserver(() => this.ready && this.el.offsetParent !== null && Plotly.Plots.resize(this.el)).observe(this.el);
    this.loop = this.loop.bind(this);
    requestAnimationFrame(this.loop);
    // fading trails need redraws even when nothing new arrives
    setInterval(() => (this.dirty = true), 500);
  }

  applyTheme() {
    this.colors = themeColors();
    this.layout = baseLayout({
      uirevision: "keep", // user zoom survives updates
      margin: { l: 40, r: 8, t: 8, b: 30 },
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
    this.dirty = true;
  }

  traces() {
    const now = Date.now() / 1000;
    const c = this.colors;
    const trail = { x: [], y: [], alpha: [] };
    const bots = { x: [], y: [], text: [], color: [], size: [], line: [], ids: [] };
    const head = { x: [], y: [] };
    for (const [id, robot] of store.robots) {
      const pts = store.trails.get(id) ?? [];
      const latest = pts.length ? pts[pts.length - 1].t : now;
      for (const p of pts) {
        const age = Math.max(0, latest - p.t);
        trail.x.push(p.x);
        trail.y.push(p.y);
        trail.alpha.push(Math.max(0.05, 1 - age / TRAIL_SECONDS));
      }
      const pos = robot.position;
      if (!pos) continue;
      bots.x.push(pos.x);
      bots.y.push(pos.y);
      bots.text.push(id);
      bots.ids.push(id);
      const stale = store.isStale(robot);
      bots.color.push(!robot.online ? c.offline : robot.estop ? c.bad : stale ? c.warn : c.accent);
      bots.size.push(id === this.selected ? 17 : 12);
      bots.line.push(id === this.selected ? 3 : 1);
      if (pos.yaw != null && Number.isFinite(pos.yaw)) {
        head.x.push(pos.x, pos.x + HEADING_M * Math.cos(pos.yaw), null);
        head.y.push(pos.y, pos.y + HEADING_M * Math.sin(pos.yaw), null);
      }
    }
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
      if (now - t.t > TAG_MEMORY_S) continue;
      tags.x.push(t.x);
      tags.y.push(t.y);
      tags.text.push(`tag ${id}`);
    }
    return [
      { type: "scattergl", mode: "markers", name: "trails", x: trail.x, y: trail.y, hoverinfo: "skip",
        // fading as numbers through a colorscale: Plotly parses no color string per point
        marker: { size: 4, color: trail.alpha, cmin: 0, cmax: 1, colorscale: TRAIL_COLORSCALE, showscale: false } },
      { type: "scattergl", mode: "lines", name: "headings", x: head.x, y: head.y, hoverinfo: "skip",
        line: { color: c.fg, width: 2 } },
      { type: "scattergl", mode: "markers+text", name: "robots", x: bots.x, y: bots.y, text: bots.text,
        customdata: bots.ids, textposition: "top center", textfont: { color: c.fg, size: 11 },
        hovertemplate: "%{customdata}<br>x %{x:.2f} m<br>y %{y:.2f} m<extra></extra>",
        marker: { size: bots.size, color: bots.color, line: { color: c.fg, width: bots.line } } },
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

  loop(t0) {
    requestAnimationFrame(this.loop);
    if (!window.Plotly || !this.dirty || this.el.offsetParent === null) return;
    if (t0 - (this.lastRender ?? -1e9) < 1000 / MAX_REDRAW_HZ) return;
    this.lastRender = t0;
    this.dirty = false;
    const start = performance.now();
    Plotly.react(this.el, this.traces(), this.layout, plotConfig);
    if (!this.ready) {
      this.ready = true;
      this.el.on("plotly_click", (ev) => {
        const p = ev.points?.find((pt) => pt.data.name === "robots");
        if (p) this.onSelect(p.customdata);
      });
    }
    this.debug.renders += 1;
    const ft = this.debug.frameTimes;
    ft.push(performance.now() - start);
    if (ft.length > 600) ft.splice(0, ft.length - 600);
  }
}
