// A finished mission's report on the missions page: how it ended, what it covered of what, in how long, each
// robot's share of the swept area, how close its robots came to each other and how often their safety filters
// stepped in (`separation`, core/separation.js), the rehearsal's prediction beside the outcome when it was
// rehearsed (rehearsalfigures.js), and the run that recorded it (its page links back here).
import { separationLines } from "../core/separation.js";
import { el } from "../core/util.js";
import { predictionVsOutcome } from "./rehearsalfigures.js";

/** The report's elements for an ended mission (MissionPublic). */
export function missionReport(m) {
  const swept = (m.progress ?? []).reduce((s, p) => s + p.swept_m2, 0);
  const area = m.workable_area_m2 ? ` of ${m.workable_area_m2.toFixed(2)} m²` : "";
  const took = m.started_at != null && m.ended_at != null ? `${Math.round(m.ended_at - m.started_at)} s` : "—";
  const how = `${m.state}${m.reason ? ` (${m.reason})` : ""}`;
  return [
    el("h3", {}, "Report"),
    el("p", { "data-testid": "mission-report-summary" },
      `${how}: covered ${(m.covered_fraction * 100).toFixed(1)}%${area} (${swept.toFixed(2)} m² swept) in ${took}, `
      + `${Math.round(m.elapsed_s)} s of it running, by ${m.robots.length} robot${m.robots.length === 1 ? "" : "s"}.`),
    ...(separationLines(m.separation, m.started_at) ?? []).map((line, i) =>
      el("p", { "data-testid": `mission-report-separation-${i}` }, `${line[0].toUpperCase()}${line.slice(1)}.`)),
    predictionVsOutcome(m) ?? "", // nothing when it was not rehearsed
    m.run_id == null
      ? el("p", { class: "muted" }, "No run recorded it.")
      : el("p", {}, "Recorded as ", el("a", { href: `/runs/${m.run_id}`, "data-link": true,
        "data-testid": "mission-report-run" }, `run ${m.run_id}`), ": replay it, export it (MCAP, Parquet)."),
  ];
}
