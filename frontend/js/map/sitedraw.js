// The site on the fleet map (read-only): the pool boundary, the keep-out zones and the wall AprilTags, as
// GET /api/site gives them. The reply may be the site itself ({boundary, keepouts, tags, version}) or
// wrapped ({version, site: {...} | null}); missing keys are tolerated, and a null site means "no site: no
// fence" (the robots then have no geofence), which the map says in words.

const KEEPOUT_FILL = "rgba(181, 42, 42, 0.18)";

/** A polygon of finite [x, y] points with at least three corners, or null. */
function polygon(points) {
  if (!Array.isArray(points)) return null;
  const ok = points.filter((p) => Array.isArray(p) && Number.isFinite(p[0]) && Number.isFinite(p[1]));
  return ok.length >= 3 ? ok.map((p) => [p[0], p[1]]) : null;
}

/** {boundary, keepouts, tags, version, minSeparation, avoidance} from GET /api/site's reply, or null when there is no site. */
export function normalizeSite(reply) {
  if (reply == null || typeof reply !== "object") return null;
  const site = "site" in reply ? reply.site : reply;
  if (site == null || typeof site !== "object") return null;
  const boundary = polygon(site.boundary);
  if (!boundary) return null; // a site is a boundary first: without one there is no fence
  const keepouts = (site.keepouts ?? site.keep_outs ?? []).map(polygon).filter(Boolean);
  const tags = [];
  for (const t of Array.isArray(site.tags) ? site.tags : []) {
    const pose = t?.pose ?? t;
    if (Number.isFinite(pose?.x) && Number.isFinite(pose?.y)) {
      tags.push({ id: t.id ?? "?", x: pose.x, y: pose.y, yaw: Number.isFinite(pose.yaw) ? pose.yaw : null });
    }
  }
  // the safety distance (safetylayer.js): the site's min_separation_m and, from a server that has it, avoidance
  const minSeparation = site.min_separation_m ?? reply.min_separation_m;
  const avoidance = site.avoidance ?? reply.avoidance ?? null;
  return { boundary, keepouts, tags, version: reply.version ?? site.version ?? "none", minSeparation, avoidance };
}

/** Closed rings as one Plotly line trace (a null between two polygons breaks the line). */
function rings(polys) {
  const x = [], y = [];
  polys.forEach((p, i) => {
    if (i > 0) {
      x.push(null);
      y.push(null);
    }
    for (const [px, py] of [...p, p[0]]) {
      x.push(px);
      y.push(py);
    }
  });
  return { x, y };
}

/** The Plotly traces of the site: boundary (dotted), keep-outs (filled red), wall tags (labelled squares). */
export function siteTraces(site, colors) {
  const boundary = rings(site ? [site.boundary] : []);
  const keepouts = rings(site?.keepouts ?? []);
  const tags = site?.tags ?? [];
  return [
    { type: "scatter", mode: "lines", name: "pool outline", ...boundary, hoverinfo: "skip",
      line: { color: colors.muted, width: 2, dash: "dot" } },
    { type: "scatter", mode: "lines", name: "keep-outs", ...keepouts, hoverinfo: "skip", fill: "toself",
      fillcolor: KEEPOUT_FILL, line: { color: colors.bad, width: 1.5 } },
    { type: "scatter", mode: "markers+text", name: "site tags", x: tags.map((t) => t.x), y: tags.map((t) => t.y),
      text: tags.map((t) => `T${t.id}`), textposition: "top center", textfont: { color: colors.fg, size: 10 },
      hoverinfo: "text", hovertext: tags.map((t) => `wall tag ${t.id}`),
      marker: { size: 8, symbol: "square-open", color: colors.fg, line: { width: 2 } } },
  ];
}

/** What the legend says about the site: its parts, or that there is none (so no fence either). */
export function siteSummary(site, error) {
  if (error) return `site not loaded (${error}): fence unknown`;
  if (!site) return "no site: no fence";
  const k = site.keepouts.length, t = site.tags.length;
  return `site v${site.version}: boundary${k ? `, ${k} keep-out${k > 1 ? "s" : ""}` : ""}${t ? `, ${t} wall tag${t > 1 ? "s" : ""}` : ""}`;
}
