// History: robots x stream x time range -> stored telemetry (downsampled by the server), zoom refetches
// finer data, export of the same selection as CSV or JSON. The query lives in the URL (deep links).
import { api } from "./api.js";
import { store } from "./store.js";
import { baseLayout, onThemeChange, plotConfig, themeColors } from "./theme.js";

const CHART_POINTS = 2000;
const EXPORT_POINTS = 10000;
const PALETTE = ["#3b7dd8", "#e4572e", "#29a36a", "#a05cd6", "#d89b3b", "#2bb6c4", "#c44f8a", "#7a8b2e"];

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

function toLocalInput(ts) {
  const d = new Date(ts * 1000);
  const pad = (n) => String(n).padStart(2, "0");
  return `${d.getFullYear()}-${pad(d.getMonth() + 1)}-${pad(d.getDate())}T${pad(d.getHours())}:${pad(d.getMinutes())}:${pad(d.getSeconds())}`;
}

function download(name, type, text) {
  const a = document.createElement("a");
  a.href = URL.createObjectURL(new Blob([text], { type }));
  a.download = name;
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(a.href), 10000);
}

export class HistoryView {
  constructor() {
    this.form = document.getElementById("history-form");
    this.robotsEl = document.getElementById("h-robots");
    this.streamEl = document.getElementById("h-stream");
    this.fieldEl = document.getElementById("h-field");
    this.startEl = document.getElementById("h-start");
    this.endEl = document.getElementById("h-end");
    this.chart = document.getElementById("history-chart");
    this.info = document.getElementById("history-info");
    this.last = null; // {query, results}
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
    document.getElementById("h-csv").addEventListener("click", () => this.export("csv"));
    document.getElementById("h-json").addEventListener("click", () => this.export("json"));
    onThemeChange(() => this.draw());
  }

  async open(params) {
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
    await this.loadStreams(params.get("stream") ?? "position");
    if (params.get("field")) this.wantField = params.get("field");
    await this.show(false);
  }

  selectedRobots() {
    return [...this.robotsEl.selectedOptions].map((o) => o.value);
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
    return { robots: this.selectedRobots(), stream: this.streamEl.value, start, end };
  }

  async fetch(q, maxPoints) {
    const results = [];
    for (const id of q.robots) {
      const page = await api.telemetry(id, { stream: q.stream, start: q.start, end: q.end, max_points: maxPoints });
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
      const url = `/history?${new URLSearchParams({ robots: q.robots.join(","), stream: q.stream, start: q.start.toFixed(0), end: q.end.toFixed(0), field: this.fieldEl.value || "" })}`;
      history.pushState({}, "", url);
    }
    this.info.textContent = "loading…";
    try {
      this.last = { query: q, results: await this.fetch(q, CHART_POINTS) };
    } catch (err) {
      this.info.textContent = `error: ${err.message}`;
      return;
    }
    this.updateFields();
    this.draw();
  }

  updateFields() {
    const fields = new Set();
    for (const page of this.last.results) for (const p of page.points.slice(0, 50)) Object.keys(flatten(p.data)).forEach((f) => fields.add(f));
    const current = this.wantField ?? this.fieldEl.value;
    this.wantField = null;
    const list = [...fields];
    const pick = list.includes(current) ? current : list.includes("x") ? "x" : list[0];
    this.fieldEl.replaceChildren(...list.map((f) => new Option(f, f, false, f === pick)));
  }

  /** What the chart shows: the zoomed-in refetch if there is one, else the whole selection. */
  shown() {
    return this.last?.zoom ?? this.last;
  }

  draw() {
    if (!this.last || !window.Plotly) return;
    const field = this.fieldEl.value;
    const c = themeColors();
    const { results } = this.shown();
    const traces = results.map((page, i) => ({
      type: "scattergl", mode: "lines", name: page.robot_id,
      x: page.points.map((p) => new Date(p.ts * 1000)),
      y: page.points.map((p) => flatten(p.data)[field] ?? null),
      line: { color: PALETTE[i % PALETTE.length], width: 1.5 },
    }));
    this.describe();
    // a new selection resets the axes; redrawing the same one (another field, a theme) keeps the zoom
    const q = this.last.query;
    Plotly.react(this.chart, traces, baseLayout({ showlegend: true, legend: { orientation: "h", y: 1.08 },
      uirevision: `${q.robots.join(",")}:${q.stream}:${q.start}:${q.end}`,
      xaxis: { gridcolor: c.grid, zerolinecolor: c.grid },
      yaxis: { title: { text: field }, gridcolor: c.grid } }), plotConfig);
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
    const down = results.some((p) => p.downsampled) ? " (downsampled: zoom in for detail)" : "";
    this.info.textContent = `${total} points${where} · ${query.stream}.${this.fieldEl.value} · ${methods}${down}`;
  }

  async onZoom(ev) {
    if (!this.last) return;
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
      const field = this.fieldEl.value;
      Plotly.restyle(this.chart, {
        x: results.map((page) => page.points.map((p) => new Date(p.ts * 1000))),
        y: results.map((page) => page.points.map((p) => flatten(p.data)[field] ?? null)),
      });
      this.describe();
    } catch (err) {
      this.info.textContent = `error: ${err.message}`;
    }
  }

  async export(kind) {
    const q = this.last?.zoom?.query ?? this.query();
    const results = await this.fetch(q, EXPORT_POINTS);
    const stamp = new Date().toISOString().replace(/[:.]/g, "-");
    if (kind === "json") {
      const rows = results.flatMap((page) => page.points.map((p) => ({ robot_id: page.robot_id, stream: page.stream, ts: p.ts, seq: p.seq, data: p.data })));
      download(`telemetry-${q.stream}-${stamp}.json`, "application/json", JSON.stringify(rows, null, 1));
      return;
    }
    const cols = new Set();
    for (const page of results) for (const p of page.points) Object.keys(flatten(p.data)).forEach((f) => cols.add(f));
    const fields = [...cols];
    const lines = [["robot_id", "stream", "ts", "seq", ...fields].join(",")];
    for (const page of results) {
      for (const p of page.points) {
        const f = flatten(p.data);
        lines.push([page.robot_id, page.stream, p.ts, p.seq, ...fields.map((k) => f[k] ?? "")].join(","));
      }
    }
    download(`telemetry-${q.stream}-${stamp}.csv`, "text/csv", `${lines.join("\n")}\n`);
  }
}
