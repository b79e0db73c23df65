// A site's boundary as the boundary editor (map/boundaryedit.js) changes it: the limits the server holds it
// to, the hint that it crosses itself, and the body PUT /api/site takes.

/** backend/schemas/site.py MAX_SITE_POLYGON_POINTS: the server refuses more corners than this. */
export const MAX_CORNERS = 200;
export const MIN_CORNERS = 3;
/** What PUT /api/site takes (SiteUpdate); GET's other keys (version, source ...) are not a site's. */
const SITE_KEYS = ["keepouts", "geofence_margin_m", "min_separation_m", "base_stations", "tags"];

/** The site as PUT /api/site takes it: the draft boundary, everything else as it was. */
export function siteUpdate(draft, base) {
  const out = { boundary: draft.map((p) => [...p]) };
  for (const key of SITE_KEYS) if (base[key] != null) out[key] = base[key];
  return out;
}

/** True when two edges that do not share a corner cross (a hint only: the server's check decides). */
export function selfCrossing(points) {
  const n = points.length;
  if (n < 4) return false;
  const orient = (a, b, c) => Math.sign((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]));
  const cross = (a, b, c, d) => orient(a, b, c) * orient(a, b, d) < 0 && orient(c, d, a) * orient(c, d, b) < 0;
  for (let i = 0; i < n; i++) {
    for (let j = i + 2; j < n; j++) {
      if (i === 0 && j === n - 1) continue; // neighbours through the closing edge
      if (cross(points[i], points[(i + 1) % n], points[j], points[(j + 1) % n])) return true;
    }
  }
  return false;
}
