// The history page's plot data, kept apart from the page so each rule is one small function: which
// fields a series offers, where its gaps are, and the Plotly traces of the time and trajectory modes.
import { robotColor } from "../core/robotcolor.js";
import { unitOf } from "../core/units.js";

/** A step this many times the series' typical (median) step is a gap: the line breaks there. */
export const GAP_FACTOR = 5;
const DASHES = ["solid", "dash", "dot", "dashdot", "longdash", "longdashdot"];
const BUCKET_EXTRAS = /_(min|max)$/;

/** Flatten a data object into numeric columns: {accel: [1,2,3]} -> accel[0], accel[1], accel[2]. */
export function flatten(data, prefix = "", out = {}) {
  for (const [k, v] of Object.entries(data ?? {})) {
    const name = prefix ? `${prefix}.${k}` : k;
    if (typeof v === "number") out[name] = v;
    else if (Array.isArray(v) && v.every((x) => typeof x === "number")) v.forEach((x, i) => (out[`${name}[${i}]`] = x));
    else if (v && typeof v === "object" && !Array.isArray(v)) flatten(v, name, out);
  }
  return out;
}

/** A stored point's plottable numbers. AprilTag frames also give ``tags`` (how many were seen) and, per
 * tag seen, ``tag<ID>.translation_mm[0..2]``, ``tag<ID>.euler_deg.yaw`` and the other numbers of its
 * detection (a frame where the tag is not seen has no value: the line breaks). */
export function values(stream, data) {
  if (stream !== "apriltag" && stream !== "apriltag_legacy") return flatten(data);
  const { detections, ...frame } = data ?? {};
  const out = flatten(frame);
  if (Array.isArray(detections)) {
    out.tags = detections.length;
    for (const d of detections) {
      if (d && Number.isInteger(d.tag_id)) {
        const { tag_id: id, family, corners, rotation, ...rest } = d;
        flatten(rest, `tag${id}`, out);
      }
    }
  }
  return out;
}

/** The fields a page offers: bucket bookkeeping (count, x_min, x_max) is not a field of its own, the
 * min/max are drawn as a band around their field instead. */
export function fieldsOf(pages) {
  const seen = new Set();
  for (const page of pages) {
    for (const p of page.points) for (const f of Object.keys(values(page.stream, p.data))) seen.add(f);
  }
  if (!pages.some((p) => p.method === "bucket-mean-minmax")) return [...seen];
  return [...seen].filter((f) => f !== "count" && !(BUCKET_EXTRAS.test(f) && seen.has(f.replace(BUCKET_EXTRAS, ""))));
}

/** The typical time step of a series (median of the positive steps), null for fewer than 3 points. */
export function typicalStep(ts) {
  const steps = [];
  for (let i = 1; i < ts.length; i++) if (ts[i] > ts[i - 1]) steps.push(ts[i] - ts[i - 1]);
  if (steps.length < 2) return null;
  steps.sort((a, b) => a - b);
  return steps[Math.floor(steps.length / 2)];
}

/** Rows with a null row inserted in every gap (a step over GAP_FACTOR x the typical one), so Plotly
 * breaks the line there instead of drawing a slope across a restart or a dropout.
 * ``rows``: [{ts, ...columns}] in time order; the inserted rows have ts midway and every column null. */
export function breakGaps(rows, columns) {
  const step = typicalStep(rows.map((r) => r.ts));
  if (step == null) return rows;
  const out = [];
  for (let i = 0; i < rows.length; i++) {
    if (i > 0 && rows[i].ts - rows[i - 1].ts > GAP_FACTOR * step) {
      const gap = { ts: (rows[i].ts + rows[i - 1].ts) / 2, gap: true };
      for (const c of columns) gap[c] = null;
      out.push(gap);
    }
    out.push(rows[i]);
  }
  return out;
}

/** "x (m)", "accel[0] (m/s²)", or the bare name when the unit is unknown or dimensionless. */
export function labelWithUnit(stream, field) {
  const u = unitOf(stream, field);
  return u ? `${field} (${u})` : field;
}

/** The y axes of a time plot: one per unit, in the order the fields come ({unit -> axis id}). */
function axesByUnit(stream, fields) {
  const axes = new Map();
  for (const f of fields) {
    const u = unitOf(stream, f) ?? "";
    if (!axes.has(u)) axes.set(u, axes.size === 0 ? "y" : `y${axes.size + 1}`);
  }
  return axes;
}

/** The min..max band of a bucketed field: one closed polygon per stretch between gaps (along the maxima,
 * back along the minima), separated by nulls so Plotly fills each on its own and never across a gap. */
function bandTrace(rows, field, meta, yaxis) {
  const x = [], y = [];
  let seg = [];
  const close = () => {
    if (seg.length) {
      for (const r of seg) x.push(new Date(r.ts * 1000)), y.push(r[`${field}_max`]);
      for (const r of [...seg].reverse()) x.push(new Date(r.ts * 1000)), y.push(r[`${field}_min`]);
      x.push(null);
      y.push(null);
    }
    seg = [];
  };
  for (const r of rows) {
    if (r[`${field}_min`] == null || r[`${field}_max`] == null) close();
    else seg.push(r);
  }
  close();
  return { type: "scatter", mode: "lines", fill: "toself", x, y, yaxis, hoverinfo: "skip", showlegend: false,
    name: `${meta.robot} ${field} min–max`, meta: { ...meta, kind: "band" }, line: { width: 0 },
    fillcolor: robotColor(meta.robot, 0.25) };
}

/** Time mode: one line per robot and field (the robot's colour, a dash per field), each on the axis of
 * its unit; bucketed position series get their min..max as a shaded band under the line. */
export function timeTraces(pages, fields) {
  const stream = pages[0]?.stream ?? "";
  const axes = axesByUnit(stream, fields);
  const traces = [];
  for (const page of pages) {
    const color = robotColor(page.robot_id);
    const rows = breakGaps(page.points.map((p) => ({ ts: p.ts, ...values(page.stream, p.data) })),
      fields.flatMap((f) => [f, `${f}_min`, `${f}_max`]));
    const x = rows.map((r) => new Date(r.ts * 1000));
    const banded = page.method === "bucket-mean-minmax";
    fields.forEach((field, k) => {
      const yaxis = axes.get(unitOf(stream, field) ?? "");
      const meta = { robot: page.robot_id, field, stream: page.stream };
      if (banded && rows.some((r) => r[`${field}_min`] != null)) traces.push(bandTrace(rows, field, meta, yaxis));
      traces.push({
        type: "scattergl", mode: "lines", name: `${page.robot_id} · ${labelWithUnit(stream, field)}`,
        meta: { ...meta, kind: "line" }, x, y: rows.map((r) => r[field] ?? null), yaxis, connectgaps: false,
        line: { color, width: 1.5, dash: DASHES[k % DASHES.length] },
      });
    });
  }
  return { traces, axes };
}

/** Plotly axis settings for the units of a time plot: the first on the left, the second at the plot's
 * right edge, more further right (the plot narrows to make room). */
export function unitAxes(axes, colors) {
  const out = {};
  const edge = 1 - 0.07 * Math.max(0, axes.size - 2);
  [...axes].forEach(([unit, id], i) => {
    const key = id === "y" ? "yaxis" : `yaxis${id.slice(1)}`;
    const title = { text: unit || "(no unit)" };
    if (i === 0) out[key] = { title, gridcolor: colors.grid, zerolinecolor: colors.grid };
    else if (i === 1) out[key] = { title, overlaying: "y", side: "right", showgrid: false, anchor: "x" };
    else out[key] = { title, overlaying: "y", side: "right", showgrid: false, anchor: "free", position: edge + 0.07 * (i - 1) };
  });
  out.xaxis = { gridcolor: colors.grid, zerolinecolor: colors.grid, title: { text: "time (local)" }, domain: [0, edge] };
  return out;
}

/** Trajectory mode: each robot's x-y path from its position stream, its markers coloured by seconds
 * since the range's start (one shared colour bar), its line in the robot's colour, broken at gaps. */
export function trajectoryTraces(pages, start) {
  const traces = [];
  pages.forEach((page, i) => {
    const rows = breakGaps(page.points.map((p) => ({ ts: p.ts, x: p.data.x ?? null, y: p.data.y ?? null })), ["x", "y"]);
    traces.push({
      type: "scattergl", mode: "lines+markers", name: page.robot_id, meta: { robot: page.robot_id, kind: "trajectory" },
      x: rows.map((r) => r.x), y: rows.map((r) => r.y), text: rows.map((r) => new Date(r.ts * 1000).toLocaleTimeString()),
      hovertemplate: "%{text}<br>x %{x:.3f} m<br>y %{y:.3f} m<extra>%{fullData.name}</extra>",
      connectgaps: false, line: { color: robotColor(page.robot_id), width: 1 },
      marker: { size: 4, color: rows.map((r) => (r.gap ? null : r.ts - start)), colorscale: "Viridis",
        cmin: 0, showscale: i === 0, colorbar: { title: { text: "s since start" }, thickness: 12 } },
    });
  });
  return traces;
}

/** The site outline (GET /api/site) as a closed dashed line. */
export function outlineTrace(site, color) {
  const b = site?.boundary ?? [];
  if (b.length < 3) return null;
  const ring = [...b, b[0]];
  return { type: "scatter", mode: "lines", name: "pool outline", meta: { kind: "outline" }, hoverinfo: "skip",
    x: ring.map((p) => p[0]), y: ring.map((p) => p[1]), line: { color, width: 2, dash: "dot" } };
}
