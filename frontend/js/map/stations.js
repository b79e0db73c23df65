// The pool map's base stations (each drawn as its x and y axes, as the seed's plot_bs_pose) and the AprilTags
// seen lately: Plotly traces (map/fleetmap.js redraws them at most twice a second, never per message).

export const BS_AXIS_M = 0.3;
export const TAG_MEMORY_S = 30;
export const BS_X_COLOR = "#d9534f";
export const BS_Y_COLOR = "#5cb85c";

/** The base stations' and tags' traces. ``seenTags``: tag id -> {x, y, t} (entries older than TAG_MEMORY_S are
 * dropped here). */
export function stationTraces(source, seenTags, colors) {
  const c = colors;
  const now = source.now();
  const bsX = { x: [], y: [] }, bsY = { x: [], y: [] }, bsP = { x: [], y: [], text: [] };
  const seen = new Set();
  for (const geo of source.geometry.values()) {
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
  for (const [id, t] of seenTags) {
    if (now - t.t > TAG_MEMORY_S) {
      seenTags.delete(id);
      continue;
    }
    tags.x.push(t.x);
    tags.y.push(t.y);
    tags.text.push(`tag ${id}`);
  }
  return [
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
