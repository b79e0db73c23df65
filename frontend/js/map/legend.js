// The pool map's legend (every mark it draws, named) and the selected robot's readout (pose and speed).
import { robotColor } from "../core/robotcolor.js";
import { TRAIL_SECONDS } from "../core/store.js";
import { el } from "../core/util.js";
import { siteSummary } from "./sitedraw.js";
import { BS_X_COLOR, BS_Y_COLOR, TAG_MEMORY_S } from "./stations.js";

/** Speed from the newest position and the trail point at least this far back. */
const SPEED_WINDOW_S = 0.5;

export function renderLegend(legendEl, colors, site, siteError) {
  const c = colors;
  const line = (color, dash) => el("span", { class: `lg-line${dash ? " dotted" : ""}`, style: `border-color:${color}` });
  const mark = (cls, color) => el("span", { class: `lg-mark ${cls}`, style: `background:${color}` });
  const item = (swatch, text) => el("span", { class: "lg-item" }, swatch, text);
  legendEl.replaceChildren(
    item(line(BS_X_COLOR), "base station x axis"), item(line(BS_Y_COLOR), "y axis"),
    item(mark("square", c.muted), "base station"), item(mark("diamond", c.warn), `AprilTag seen (${TAG_MEMORY_S} s)`),
    el("span", { class: `lg-item${site ? "" : " site-none"}`, "data-testid": "site-status",
      title: siteSummary(site, siteError) }, site ? line(c.muted, true) : "⚠",
    site ? "pool outline" : siteSummary(site, siteError)),
    site?.keepouts.length ? item(mark("square", c.bad), "keep-out") : "",
    site?.tags.length ? item(el("span", { class: "lg-mark square-open" }), "wall tag (site)") : "",
    item(el("span", { class: "lg-mark round" }), "robot, its own colour; ring: red e-stop, amber stale; grey: offline; ! open alarm"),
    item(el("span", { class: "lg-trail" }), `trail ${TRAIL_SECONDS} s`),
  );
}

/** The selected robot's pose and speed. */
export function renderReadout(readoutEl, source, selected) {
  const robot = selected ? source.robots.get(selected) : null;
  const p = robot?.position;
  if (!robot || !p) {
    readoutEl.textContent = selected ? `${selected}: no position yet` : "Select a robot for its pose and speed.";
    delete readoutEl.dataset.robot;
    return;
  }
  const speed = groundSpeed(source, selected, p);
  const yaw = p.yaw != null && Number.isFinite(p.yaw) ? `${((p.yaw * 180) / Math.PI).toFixed(1)}°` : "—";
  readoutEl.dataset.robot = selected;
  readoutEl.replaceChildren(
    el("span", { class: "robot-dot", style: `background:${robotColor(selected)}` }),
    el("strong", {}, selected),
    ` x ${p.x.toFixed(3)} m · y ${p.y.toFixed(3)} m · z ${(p.z ?? 0).toFixed(3)} m · yaw ${yaw} · `,
    el("span", { dataset: { testid: "map-readout-speed" } }, speed == null ? "speed —" : `speed ${speed.toFixed(2)} m/s`),
    robot.online ? "" : el("span", { class: "muted" }, " · offline: last known pose"),
  );
}

/** Ground speed (m/s) from the newest position and the trail point SPEED_WINDOW_S or more before it. */
export function groundSpeed(source, id, p) {
  const trail = source.trails.get(id) ?? [];
  for (let i = trail.length - 1; i >= 0; i--) {
    const dt = p.ts - trail[i].t;
    if (dt >= SPEED_WINDOW_S) return Math.hypot(p.x - trail[i].x, p.y - trail[i].y) / dt;
  }
  return null;
}
