// A rehearsal's figures in words (POST /api/missions/{id}/rehearsal, or the summary a mission keeps in its
// `rehearsal`): what the twin predicts (duration, coverage, closest approach, safety filters, blocked legs,
// contacts, fence violations) and how fast it ran; and, once the mission ran for real, the prediction beside
// the outcome (its running time, its coverage, the closest approach of its separation report).
import { el } from "../core/util.js";

const seconds = (s) => (s == null ? "—" : `${Math.round(s)} s`);
const percent = (f) => (f == null ? "—" : `${(f * 100).toFixed(1)}%`);
const metres = (m) => (m == null ? "—" : `${m.toFixed(3)} m`);

/** Each figure: its key in ``predicted``, its label, how it reads (``p``: the whole prediction). */
const FIGURES = [
  ["duration_s", "duration", (v, p) => `${seconds(v)}${p.outcome && p.outcome !== "completed" ? ` (${p.outcome})` : ""}`],
  ["covered_fraction", "coverage", (v) => percent(v)],
  ["min_separation_m", "closest approach",
    (v, p) => `${metres(v)}${v != null && p.closest_pair ? ` (${p.closest_pair.join(" and ")})` : ""}`],
  ["filter_interventions", "safety filter interventions",
    (v, p) => `${v ?? 0}${p.filter_seconds ? ` (${p.filter_seconds.toFixed(1)} s)` : ""}`],
  ["blocked_legs", "blocked legs", (v) => String(v ?? 0)],
  ["collisions", "contacts", (v) => String(v ?? 0)],
  ["fence_violations", "fence violations", (v) => String(v ?? 0)],
];
/** How a spread's figure reads (several seeds): the same units as the figure. */
const SPREAD_UNITS = { duration_s: seconds, covered_fraction: percent, min_separation_m: metres };

/** "seed 41 · simulated 125 s in 2.2 s, ×57" (several seeds: each of them). */
export function speedLine(r) {
  const seeds = r.seeds?.length > 1 ? `seeds ${r.seeds.join(", ")}` : `seed ${r.seed}`;
  const factor = r.speed_factor != null ? `, ×${Math.round(r.speed_factor)}` : "";
  const took = r.took_s != null ? ` in ${r.took_s.toFixed(1)} s` : "";
  return `${seeds} · simulated ${seconds(r.predicted?.duration_s)}${took}${factor}`;
}

/** The figures' table of a rehearsal (its answer or the summary a mission keeps). */
export function figuresTable(r) {
  const p = r.predicted ?? {};
  const spreadOf = (key) => {
    const s = r.spread?.[key];
    if (!s) return "";
    const fmt = SPREAD_UNITS[key] ?? String;
    return ` · ${fmt(s.min)} to ${fmt(s.max)} over ${r.seeds.length} seeds`;
  };
  return el("table", { class: "rehearsal-figures", "data-testid": "rehearsal-figures" },
    el("tbody", {}, ...FIGURES.map(([key, label, read]) => el("tr", { "data-figure": key },
      el("th", { scope: "row" }, label), el("td", {}, read(p[key], p), el("span", { class: "muted" }, spreadOf(key)))))));
}

/** A signed difference, "+6 s" or "−1.2%"; empty when either side is missing. */
function delta(predicted, actual, fmt) {
  if (predicted == null || actual == null) return "";
  const d = actual - predicted;
  return ` (${d >= 0 ? "+" : "−"}${fmt(Math.abs(d))})`;
}

/** Prediction and outcome side by side, for a mission that ended and was rehearsed before it started; null
 * otherwise. The outcome: the mission's running time, its coverage and its separation report's closest
 * approach. */
export function predictionVsOutcome(m) {
  const p = m.rehearsal?.predicted;
  if (!p) return null;
  const closest = m.separation?.closest?.distance_m ?? null;
  const rows = [
    ["duration_s", "duration", p.duration_s, m.elapsed_s, seconds, (d) => `${Math.round(d)} s`],
    ["covered_fraction", "coverage", p.covered_fraction, m.type === "coverage" ? m.covered_fraction : null,
      percent, (d) => `${(d * 100).toFixed(1)}%`],
    ["min_separation_m", "closest approach", p.min_separation_m, closest, metres, (d) => `${d.toFixed(3)} m`],
  ];
  const when = m.rehearsal.at ? new Date(m.rehearsal.at * 1000).toLocaleString([], { timeStyle: "short", dateStyle: "short" }) : "";
  const col = (text) => el("th", { scope: "col" }, text);
  return el("table", { class: "rehearsal-figures rehearsal-vs", "data-testid": "rehearsal-vs-outcome" },
    el("caption", {}, `Rehearsed (seed ${m.rehearsal.seed}${when ? `, ${when}` : ""}) and run`),
    el("thead", {}, el("tr", {}, el("td", {}), col("predicted"), col("outcome"))),
    el("tbody", {}, ...rows.map(([key, label, predicted, actual, fmt, fmtDelta]) => el("tr", { "data-figure": key },
      el("th", { scope: "row" }, label),
      el("td", { "data-side": "predicted" }, fmt(predicted)),
      el("td", { "data-side": "outcome" }, fmt(actual),
        el("span", { class: "muted" }, delta(predicted, actual, fmtDelta)))))));
}
