// The robots on the pool map's live canvas: their fading trails, and each robot's heading, marker (its own
// colour; its state as a ring: red e-stop, amber stale; grey fill offline; a "!" badge for an open alarm)
// and label. map/fleetmap.js calls these on every canvas pass, for every robot in one pass.
import { robotColor } from "../core/robotcolor.js";
import { TRAIL_SECONDS } from "../core/store.js";

const HEADING_M = 0.25;
const TRAIL_MAX_ALPHA = 0.55;

/** Trails (under the robots): one small square per kept point in the robot's colour, fading with age. */
export function drawTrails(ctx, proj, source) {
  const { px, py } = proj;
  const { robots, trails } = source;
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
}

/** Heading line, marker and the label on the side away from the heading, so the line never runs through the
 * name. Returns the label's box and the heading segment as drawn (CSS pixels). */
export function drawRobot(ctx, proj, colors, source, { id, robot, x, y, selected }) {
  const c = colors;
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
  const stale = source.isStale(robot);
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
  return { x: lx - w / 2, y: ly - h / 2, w, h, heading };
}
