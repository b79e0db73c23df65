// History: robots x stream x fields x time range -> stored telemetry (bucketed by the server when the
// range holds more than CHART_POINTS), plotted over time (one axis per unit, min/max bands when bucketed,
// lines broken at gaps) or as x-y trajectories over the pool outline. Zoom refetches finer data. Exports
// are the server's streamed exports of the stored points unless "bucketed" is ticked, and say which.
// The query lives in the URL (deep links).
import { api } from "../core/api.js";
import { fieldsOf, outlineTrace, timeTraces, trajectoryTraces, unitAxes } from "./historyplot.js";
import { store } from "../core/store.js";
import { baseLayout, onThemeChange, plotConfig, themeColors } from "../core/theme.js";
import { loadUnits } from "../core/units.js";

const CHART_POINTS = 2000;
/** A bucketed export's points per series (the API's maximum). */
const EXPORT_BUCKETS = 10000;

function toLocalInput(ts) {
  const d = new Date(ts * 1000);
  const pad = (n) => String(n).padStart(2, "0");
  return `${d.getFullYear()}-${pad(d.getMonth() + 1)}-${pad(d.getDate())}T${pad(d.getHours())}:${pad(d.getMinutes())}:${pad(d.getSeconds())}`;
}

function download(name, blob) {
  const a = document.createElement("a");
  a.href = URL.createObjectURL(blob);
  a.download = name;
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(a.href), 10000);
}

/** Reads a streamed response into a Blob, counting its lines as they arrive (progress for long exports). */
async function collect(res, onProgress) {
  const reader = res.body.getReader();
  const parts = [];
  let lines = 0;
  for (;;) {
    const { done, value } = await reader.read();
    if (done) break;
    parts.push(value);
    for (let i = value.indexOf(10); i !== -1; i = value.indexOf(10, i + 1)) lines++;
    onProgress(lines);
  }
  return { blob: new Blob(parts), lines };
}

/** Lines before a CSV export's first row: its "#" comment lines and the header row. */
async function csvHeadLines(blob) {
  const head = (await blob.slice(0, 16384).text()).split("\n");
  let n = 0;
  while (n < head.length && head[n].startsWith("#")) n++;
  return n + 1;
}

export class HistoryView {
  constructor() {
    this.form = document.getElementById("history-form");
    this.robotsEl = document.getElementById("h-robots");
    this.streamEl = document.getElementById("h-stream");
    this.fieldEl = document.getElementById("h-field");
    this.startEl = document.getElementById("h-start");
    this.endEl = document.getElementById("h-end");
    this.bucketedEl = document.getElementById("h-bucketed");
    this.recvEl = document.getElementById("h-recv");
    this.chart = document.getElementById("history-chart");
    this.info = document.getElementById("history-info");
    this.exportInfo = document.getElementById("history-export-info");
    this.last = null; // {query, results}
    this.site = null;
    this.relayoutBound = false;
    this.form.addEventListener("submit", (ev) => {
      ev.preventDefault();
      this.show(true);
    });
    for (const b of this.form.querySelectorAll("[data-range]")) {
      b.addEventListener("click", () => {
        const now = Date.now() / 1000;
        this.startEl.value = toLocalInput(now - Number(b.dataset.range));
        this.endEl.value = toLocalInput(now);
        for (const o of this.form.querySelectorAll("[data-range]")) o.classList.toggle("active", o === b);
        this.show(true);
      });
    }
    this.robotsEl.addEventListener("change", () => this.loadStreams());
    this.streamEl.addEventListener("change", () => this.show(true));
    this.fieldEl.addEventListener("change", () => this.draw());
    for (const r of this.form.querySelectorAll("[name=h-mode]")) r.addEventListener("change", () => this.show(true));
    this.recvEl.addEventListener("change", () => this.show(true));
    document.getElementById("h-csv").addEventListener("click", () => this.export("csv"));
    document.getElementById("h-json").addEventListener("click", () => this.export("json"));
    onThemeChange(() => this.draw());
  }

  get mode() {
    return this.form.querySelector("[name=h-mode]:checked")?.value ?? "time";
  }

  set mode(value) {
    for (const r of this.form.querySelectorAll("[name=h-mode]")) r.checked = r.value === value;
  }

  async open(params) {
    await loadUnits();
    if (!this.site) this.site = await api.get("/api/site").catch(() => null);
    const wanted = (params.get("robots") ?? "").split(",").filter(Boolean);
    let known = [...store.robots.keys()];
    try {
      known = (await api.robots()).map((r) => r.id); // the live snapshot may not have arrived yet
    } catch {
      /* keep what the live connection knows */
    }
    const robots = [...new Set([...known, ...wanted])].sort();
    this.robotsEl.replaceChildren(...robots.map((id) => new Option(id, id, false, wanted.includes(id))));
    if (!wanted.length && robots.length) this.robotsEl.options[0].selected = true;
    const now = Date.now() / 1000;
    this.startEl.value = toLocalInput(Number(params.get("start") ?? now - 300));
    this.endEl.value = toLocalInput(Number(params.get("end") ?? now));
    this.mode = params.get("mode") === "xy" ? "xy" : "time";
    this.recvEl.checked = params.get("time") === "recv_ts";
    await this.loadStreams(params.get("stream") ?? "position");
    const fields = params.get("fields") ?? params.get("field");
    if (fields) this.wantFields = fields.split(",").filter(Boolean);
    await this.show(false);
  }

  selectedRobots() {
    return [...this.robotsEl.selectedOptions].map((o) => o.value);
  }

  selectedFields() {
    return [...this.fieldEl.selectedOptions].map((o) => o.value);
  }

  async loadStreams(prefer) {
    const names = new Set();
    for (const id of this.selectedRobots()) {
      try {
        for (const s of await api.streams(id)) if (s.count > 0 || s.last_ts) names.add(s.stream);
      } catch {
        /* robot without stored data */
      }
    }
    const current = prefer ?? this.streamEl.value;
    const list = [...names].sort();
    this.streamEl.replaceChildren(...list.map((n) => new Option(n, n, false, n === current)));
  }

  query() {
    const start = new Date(this.startEl.value).getTime() / 1000;
    const end = new Date(this.endEl.value).getTime() / 1000;
    // a trajectory is drawn from the position stream whatever stream the form shows
    const stream = this.mode === "xy" ? "position" : this.streamEl.value;
    return { robots: this.selectedRobots(), stream, start, end, mode: this.mode, time: this.recvEl.checked ? "recv_ts" : "ts" };
  }

  /** Each robot's page. On the server's clock (``time=recv_ts``) every point is placed at its ``recv_ts``
   * (points without one are left out, and the rest sorted by it); the range still selects by the robot's ts. */
  async fetch(q, maxPoints) {
    const results = [];
    for (const id of q.robots) {
      const params = { stream: q.stream, start: q.start, end: q.end, max_points: maxPoints };
      const page = await api.telemetry(id, q.time === "recv_ts" ? { ...params, time: "recv_ts" } : params);
      if (q.time === "recv_ts") {
        page.points = page.points.filter((p) => p.recv_ts != null).map((p) => ({ ...p, robot_ts: p.ts, ts: p.recv_ts }))
          .sort((a, b) => a.ts - b.ts);
      }
      results.push(page);
    }
    return results;
  }

  async show(pushUrl) {
    const q = this.query();
    if (!q.robots.length || !q.stream || !Number.isFinite(q.start) || !Number.isFinite(q.end)) {
      this.info.textContent = "Pick robots, a stream and a time range.";
      return;
    }
    if (pushUrl) {
      const params = { robots: q.robots.join(","), stream: this.streamEl.value, start: q.start.toFixed(0),
        end: q.end.toFixed(0), fields: this.selectedFields().join(","), mode: q.mode, ...(q.time === "recv_ts" ? { time: "recv_ts" } : {}) };
      history.pushState({}, "", `/history?${new URLSearchParams(params)}`);
    }
    this.info.textContent = "loading…";
    try {
      this.last = { query: q, results: await this.fetch(q, CHART_POINTS) };
      // run markers in the range (docs/runs.md) are drawn as vertical lines on the time plot
      this.markers = await api.get(`/api/events?kind=marker&start=${q.start.toFixed(3)}&end=${q.end.toFixed(3)}&limit=500`).catch(() => []);
    } catch (err) {
      this.info.textContent = `error: ${err.message}`;
      return;
    }
    if (q.mode === "time") this.updateFields();
    this.fieldEl.disabled = q.mode === "xy"; // a trajectory is x against y
    this.draw();
  }

  updateFields() {
    const list = fieldsOf(this.last.results);
    const wanted = (this.wantFields ?? this.selectedFields()).filter((f) => list.includes(f));
    this.wantFields = null;
    const pick = wanted.length ? wanted : list.includes("x") ? ["x"] : list.slice(0, 1);
    this.fieldEl.replaceChildren(...list.map((f) => new Option(f, f, false, pick.includes(f))));
  }

  /** What the chart shows: the zoomed-in refetch if there is one, else the whole selection. */
  shown() {
    return this.last?.zoom ?? this.last;
  }

  draw() {
    if (!this.last || !window.Plotly) return;
    const c = themeColors();
    const { results } = this.shown();
    const q = this.last.query;
    const common = { showlegend: true, legend: { orientation: "h", y: 1.1 },
      uirevision: `${q.mode}:${q.robots.join(",")}:${q.stream}:${q.start}:${q.end}` };
    let traces, layout;
    if (q.mode === "xy") {
      traces = trajectoryTraces(results, q.start);
      const outline = outlineTrace(this.site, c.muted);
      if (outline) traces.unshift(outline);
      layout = baseLayout({ ...common, margin: { l: 50, r: 10, t: 10, b: 40 },
        xaxis: { title: { text: "x (m)" }, gridcolor: c.grid, zerolinecolor: c.grid },
        yaxis: { title: { text: "y (m)" }, scaleanchor: "x", scaleratio: 1, gridcolor: c.grid, zerolinecolor: c.grid } });
    } else {
      const built = timeTraces(results, this.selectedFields());
      traces = built.traces;
      layout = baseLayout({ ...common, margin: { l: 50, r: 50, t: 10, b: 40 }, ...unitAxes(built.axes, c) });
      const marks = (this.markers ?? []).filter((m) => !m.robot_id || q.robots.includes(m.robot_id));
      layout.shapes = marks.map((m) => ({ type: "line", xref: "x", yref: "paper", x0: new Date(m.ts * 1000),
        x1: new Date(m.ts * 1000), y0: 0, y1: 1, line: { color: c.warn, width: 1, dash: "dash" } }));
      layout.annotations = marks.map((m) => ({ x: new Date(m.ts * 1000), xref: "x", yref: "paper", y: 1,
        text: m.detail?.text ?? "marker", showarrow: false, yanchor: "bottom", font: { size: 10 } }));
    }
    this.describe();
    // a new selection resets the axes; redrawing the same one (other fields, a theme, a zoom) keeps them
    Plotly.react(this.chart, traces, layout, plotConfig);
    if (!this.relayoutBound) {
      this.relayoutBound = true;
      this.chart.on("plotly_relayout", (ev) => this.onZoom(ev));
    }
  }

  describe() {
    const { query, results } = this.shown();
    const total = results.reduce((s, p) => s + p.points.length, 0);
    const methods = [...new Set(results.map((p) => p.method))].join(", ");
    const where = this.last.zoom ? " in the zoomed range" : "";
    const what = query.mode === "xy" ? "position x–y trajectory" : `${query.stream}.${this.selectedFields().join(", ")}`;
    const widths = results.map((p) => p.bucket_s).filter(Boolean);
    const down = results.some((p) => p.downsampled)
      ? ` (bucketed${widths.length ? ` to ${Math.max(...widths).toPrecision(3)} s` : ""}: means, with min–max bands; zoom in for the stored points)`
      : "";
    const clock = query.time === "recv_ts" ? " · on the server's clock (recv_ts)" : "";
    this.info.textContent = `${total} points${where} · ${what} · ${methods}${down}${clock}`;
  }

  async onZoom(ev) {
    if (!this.last || this.last.query.mode !== "time") return;
    if (ev["xaxis.autorange"]) { // double click: back to the whole selection
      if (this.last.zoom) {
        this.last.zoom = null;
        this.draw();
      }
      return;
    }
    const a = ev["xaxis.range[0]"] ?? ev["xaxis.range"]?.[0];
    const b = ev["xaxis.range[1]"] ?? ev["xaxis.range"]?.[1];
    if (a == null || b == null) return;
    // plotly gives local "YYYY-MM-DD HH:MM:SS.sss" strings: with a "T" every browser reads them as local time
    const secs = (v) =>
      (typeof v === "number" ? v : v instanceof Date ? v.getTime() : new Date(String(v).replace(" ", "T")).getTime()) / 1000;
    const q = { ...this.last.query, start: secs(a), end: secs(b) };
    if (!Number.isFinite(q.start) || !Number.isFinite(q.end) || q.end <= q.start) return;
    const seq = (this.zoomSeq = (this.zoomSeq ?? 0) + 1);
    this.info.textContent = "loading the zoomed range…";
    try {
      const results = await this.fetch(q, CHART_POINTS);
      if (seq !== this.zoomSeq) return; // a newer zoom is under way
      this.last.zoom = { query: q, results };
      this.draw();
    } catch (err) {
      this.info.textContent = `error: ${err.message}`;
    }
  }

  /** The server's export of the shown selection (the zoomed range if zoomed): every stored point,
   * streamed, unless "bucketed" is ticked. JSON is the raw NDJSON export as one array. */
  async export(kind) {
    const q = this.last?.zoom?.query ?? this.query();
    if (!q.robots.length || !q.stream || !Number.isFinite(q.start) || !Number.isFinite(q.end)) {
      this.exportInfo.textContent = "Pick robots, a stream and a time range to export.";
      return;
    }
    const bucketed = kind === "csv" && this.bucketedEl.checked;
    const params = new URLSearchParams({ robots: q.robots.join(","), streams: q.stream, start: q.start, end: q.end,
      format: kind === "csv" ? "csv" : "ndjson", ...(bucketed ? { max_points: EXPORT_BUCKETS } : { raw: "true" }),
      ...(q.time === "recv_ts" ? { time: "recv_ts" } : {}) });
    this.exportInfo.textContent = "exporting…";
    const res = await fetch(`/api/telemetry?${params}`, { credentials: "same-origin" });
    if (!res.ok) {
      const body = await res.json().catch(() => ({}));
      const reason = typeof body.detail === "string" ? body.detail : `${res.status} ${res.statusText}`;
      this.exportInfo.textContent = `export refused: ${reason}`;
      return;
    }
    const downsampled = res.headers.get("X-Fleet-Downsampled") === "true";
    const label = downsampled ? "bucketed" : "raw";
    const stamp = new Date().toISOString().replace(/[:.]/g, "-");
    const name = `telemetry-${q.stream}-${label}-${stamp}`;
    const { blob, lines } = await collect(res, (n) => (this.exportInfo.textContent = `exporting… ${n} lines`));
    let rows;
    if (kind === "json") {
      const items = (await blob.text()).split("\n").filter(Boolean).map((line) => JSON.parse(line));
      rows = items.length;
      download(`${name}.json`, new Blob([JSON.stringify(items, null, 1)], { type: "application/json" }));
    } else {
      rows = lines - (await csvHeadLines(blob));
      download(`${name}.csv`, new Blob([blob], { type: "text/csv" }));
    }
    this.exportInfo.dataset.kind = label;
    this.exportInfo.textContent = downsampled
      ? `Exported ${rows} rows BUCKETED (${res.headers.get("X-Fleet-Method")}): means per time bucket with min/max, not the stored points.`
      : `Exported ${rows} stored points (raw, every row as stored).`;
  }
}
