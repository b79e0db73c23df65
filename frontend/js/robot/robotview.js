// One robot's page: camera with overlay, drive pad, live charts (x/y/z, IMU, tag count, 3-D) and its
// command log. Charts keep the last WINDOW_S seconds and redraw at most REDRAW_HZ times per second.
import { CameraView } from "./camera.js";
import { CommandLog } from "../drive/commandlog.js";
import { DrivePad, driver } from "../drive/drive.js";
import { robotColor } from "../core/robotcolor.js";
import { renderSafety } from "./robotsafety.js";
import { store } from "../core/store.js";
import { baseLayout, onThemeChange, plotConfig, themeColors } from "../core/theme.js";
import { ago, el } from "../core/util.js";

const WINDOW_S = 60;
const REDRAW_HZ = 5;

function series() {
  return { t: [], cols: {} };
}

export class RobotView {
  constructor() {
    this.robotId = null;
    this.camera = new CameraView({
      canvas: document.getElementById("camera-canvas"),
      overlay: document.getElementById("overlay-canvas"),
      info: document.getElementById("camera-info"),
      toggle: document.getElementById("overlay-toggle"),
    });
    this.pad = new DrivePad(document.getElementById("robot-drive-host"));
    this.log = new CommandLog(document.getElementById("robot-log-host"), { testid: "robot-command-log" });
    this.data = { position: series(), imu: series(), apriltag: series() };
    this.dirty = false;
    store.on("telemetry", (msg) => this.onTelemetry(msg));
    store.on("robots", (id) => id === this.robotId && this.renderHead());
    setInterval(() => this.redraw(), 1000 / REDRAW_HZ);
    setInterval(() => this.renderHead(), 1000);
    onThemeChange(() => (this.dirty = true));
  }

  open(robotId) {
    this.robotId = robotId;
    this.data = { position: series(), imu: series(), apriltag: series() };
    driver.setRobot(robotId);
    this.log.setRobot(robotId);
    this.camera.open(robotId);
    for (const id of ["chart-xyz", "chart-imu", "chart-tags", "chart-3d"]) {
      const node = document.getElementById(id);
      if (window.Plotly && node.data) Plotly.purge(node);
    }
    this.renderHead();
    this.dirty = true;
  }

  close() {
    this.robotId = null;
    this.camera.close();
  }

  push(name, ts, values) {
    const s = this.data[name];
    s.t.push(ts);
    for (const [k, v] of Object.entries(values)) (s.cols[k] ??= []).push(v);
    const cutoff = ts - WINDOW_S;
    let drop = 0;
    while (drop < s.t.length && s.t[drop] < cutoff) drop++;
    if (drop) {
      s.t.splice(0, drop);
      for (const c of Object.values(s.cols)) c.splice(0, drop);
    }
  }

  onTelemetry(msg) {
    if (msg.robot_id !== this.robotId) return;
    const d = msg.data;
    if (msg.stream === "position") this.push("position", msg.ts, { x: d.x, y: d.y, z: d.z ?? 0 });
    else if (msg.stream === "imu" && Array.isArray(d.accel) && Array.isArray(d.gyro)) {
      this.push("imu", msg.ts, { ax: d.accel[0], ay: d.accel[1], az: d.accel[2], gx: d.gyro[0], gy: d.gyro[1], gz: d.gyro[2] });
    } else if (msg.stream === "apriltag") this.push("apriltag", msg.ts, { n: (d.detections ?? []).length });
    else return;
    this.dirty = true;
  }

  renderHead() {
    if (!this.robotId) return;
    const r = store.robots.get(this.robotId);
    document.getElementById("robot-title").textContent = this.robotId;
    renderSafety(document.getElementById("robot-safety"), r);
    const badges = document.getElementById("robot-badges");
    const details = document.getElementById("robot-details");
    this.showCamera(r);
    if (!r) {
      badges.replaceChildren(el("span", { class: "badge offline" }, "unknown robot"));
      details.replaceChildren();
      return;
    }
    const state = !r.online ? "offline" : store.isStale(r) ? "stale" : "online";
    badges.replaceChildren(...[el("span", { class: `badge ${state}` }, state),
      r.legacy ? el("span", { class: "badge legacy", title: "old framework: no deadman of its own" }, "legacy") : null,
      r.hold ? el("span", { class: "badge stopped", "data-testid": "badge-held" }, "held") : null,
      r.estop ? el("span", { class: "badge stopped", title: "this robot reports its e-stop latched" }, "e-stop") : null].filter(Boolean));
    const p = r.position;
    const sensors = Object.entries(r.sensors ?? {}).map(([n, s]) => `${n}: ${s.ok === false ? `FAILING ${s.error ?? ""}` : "ok"}`);
    details.replaceChildren(el("dl", {},
      el("dt", {}, "Position"), el("dd", {}, p ? `x ${p.x.toFixed(3)}  y ${p.y.toFixed(3)}  z ${(p.z ?? 0).toFixed(3)}${p.yaw != null ? `  yaw ${(p.yaw * 180 / Math.PI).toFixed(1)}°` : ""}` : "—"),
      el("dt", {}, "Last seen"), el("dd", {}, ago(r.last_seen)),
      el("dt", {}, "Agent"), el("dd", {}, r.agent_version || "—"),
      el("dt", {}, "Sensors"), el("dd", {}, sensors.join("\n") || (r.capabilities?.sensors ?? []).join(", ") || "—"),
      el("dt", {}, "Commands"), el("dd", {}, (r.capabilities?.commands ?? []).join(", ") || "—")));
  }

  /** A robot without a camera gets a line saying so, not a big black "no frames" box. */
  showCamera(robot) {
    const known = Boolean(robot?.capabilities);
    const has = known && (robot.capabilities.sensors ?? []).includes("camera");
    document.querySelector(".camera-box").classList.toggle("absent", !has);
    document.getElementById("no-camera").hidden = !known || has;
    document.getElementById("camera-info").hidden = !has;
    document.getElementById("overlay-toggle").parentElement.hidden = !has;
  }

  // (forgetting a robot that is gone: the Safety panel's admin button, robotsafety.js)

  redraw() {
    if (!this.robotId || !this.dirty || !window.Plotly || document.getElementById("view-robot").hidden) return;
    this.dirty = false;
    const c = themeColors();
    const pos = this.data.position, imu = this.data.imu, tags = this.data.apriltag;
    const t = (s) => s.t.map((x) => new Date(x * 1000));
    const line = (s, k, color, name) => ({ type: "scattergl", mode: "lines", x: t(s), y: s.cols[k] ?? [], name, line: { color, width: 1.5 } });
    const legend = { showlegend: true, legend: { orientation: "h", y: 1.12 } };
    Plotly.react("chart-xyz", [line(pos, "x", "#e4572e", "x"), line(pos, "y", "#29a36a", "y"), line(pos, "z", "#3b7dd8", "z")],
      baseLayout({ ...legend, uirevision: this.robotId, yaxis: { title: { text: "m" }, gridcolor: c.grid } }), plotConfig);
    Plotly.react("chart-imu", [line(imu, "ax", "#e4572e", "ax"), line(imu, "ay", "#29a36a", "ay"), line(imu, "az", "#3b7dd8", "az"),
      { ...line(imu, "gz", "#a05cd6", "gz (rad/s)"), yaxis: "y2" }],
    baseLayout({ ...legend, uirevision: this.robotId, yaxis: { title: { text: "m/s²" }, gridcolor: c.grid },
      yaxis2: { overlaying: "y", side: "right", title: { text: "rad/s" }, showgrid: false, automargin: true },
      margin: { l: 44, r: 56, t: 10, b: 36 } }), plotConfig);
    Plotly.react("chart-tags", [{ type: "scattergl", mode: "lines", x: t(tags), y: tags.cols.n ?? [], line: { color: c.warn, shape: "hv" } }],
      baseLayout({ uirevision: this.robotId, yaxis: { rangemode: "tozero", dtick: 1, gridcolor: c.grid } }), plotConfig);
    const bs = [];
    for (const geo of store.geometry.values()) for (const b of geo.base_stations ?? []) bs.push(b);
    Plotly.react("chart-3d", [
      { type: "scatter3d", mode: "lines", x: pos.cols.x ?? [], y: pos.cols.y ?? [], z: pos.cols.z ?? [], line: { color: robotColor(this.robotId), width: 4 }, name: "trail" },
      { type: "scatter3d", mode: "markers+text", x: bs.map((b) => b.position[0]), y: bs.map((b) => b.position[1]),
        z: bs.map((b) => b.position[2]), text: bs.map((b) => `BS ${b.id}`), marker: { size: 4, color: c.muted, symbol: "square" }, name: "base stations" },
    ], baseLayout({ uirevision: this.robotId, margin: { l: 0, r: 0, t: 0, b: 0 },
      scene: { aspectmode: "data", xaxis: { title: { text: "x" } }, yaxis: { title: { text: "y" } }, zaxis: { title: { text: "z" } } } }), plotConfig);
  }
}
