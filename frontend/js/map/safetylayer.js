// "Safety distance" on the pool map (issue 31, docs/safety.md): around the selected robot, the distance its
// safety filter keeps to every other robot's centre (the site's min_separation_m, plus the avoidance margin_m
// when GET /api/site has `avoidance` and it is enabled; speed and a stale fix add more on the robot), dashed
// and lightly filled, and its body (BODY_RADIUS_M of fleet_protocol/neighbours.py), solid. Another robot's
// centre inside the dashed circle is closer than the filter allows. Off until switched on under Layers: the
// map stays as it was for whoever does not ask for it.
import { robotColor } from "../core/robotcolor.js";

/** A robot's body radius (m): fleet_protocol/neighbours.py BODY_RADIUS_M. */
export const BODY_RADIUS_M = 0.1;
/** A site that names none (an older server): the default of the site's min_separation_m. */
const DEFAULT_MIN_SEPARATION_M = 0.3;

/** The safety distance of a site (normalizeSite's): {separation, margin, radius} in metres. */
export function safetyDistance(site) {
  const separation = Number.isFinite(site?.minSeparation) ? site.minSeparation : DEFAULT_MIN_SEPARATION_M;
  const a = site?.avoidance;
  const margin = a && a.enabled !== false && Number.isFinite(a.margin_m) ? a.margin_m : 0;
  return { separation, margin, radius: separation + margin };
}

/** The layer (layers.js) for ``map``: drawn over the robots, after they were placed (map.drawn). ``drawn``
 * holds what it drew last (CSS pixels in the map element; tests read it), null when nothing. */
export function safetyLayer(map) {
  return {
    id: "safety",
    label: "safety distance (selected robot)",
    off: true,
    drawn: null,
    draw(ctx, proj) {
      this.drawn = null;
      const at = map.selected == null ? null : map.drawn.get(map.selected);
      if (!at) return;
      const d = safetyDistance(map.site);
      const perMetre = Math.abs(proj.px(1) - proj.px(0));
      const r = d.radius * perMetre, body = BODY_RADIUS_M * perMetre;
      ctx.save();
      ctx.strokeStyle = robotColor(map.selected);
      ctx.fillStyle = robotColor(map.selected, 0.12);
      ctx.lineWidth = 2;
      ctx.setLineDash([6, 4]);
      ctx.beginPath();
      ctx.arc(at.px, at.py, r, 0, 2 * Math.PI);
      ctx.fill();
      ctx.stroke();
      ctx.setLineDash([]);
      ctx.lineWidth = 1.5;
      ctx.beginPath();
      ctx.arc(at.px, at.py, body, 0, 2 * Math.PI);
      ctx.stroke();
      ctx.restore();
      this.drawn = { robot: map.selected, px: at.px, py: at.py, radius_m: d.radius, separation_m: d.separation,
        margin_m: d.margin, radius_px: r, body_px: body };
    },
  };
}
