// How close the robots came and how often their safety filters stepped in, in words (issue 31): the
// `separation` of a run's summary (GET /api/runs/{id}) and of an ended mission's report (GET /api/missions/{id}),
// on the run's page and in the mission's report alike (docs/runs.md, Separation).

const plural = (n, word) => `${n} ${word}${n === 1 ? "" : "s"}`;

/** [closest approach, violations and contacts, interventions] as three short lines; null without figures.
 * ``start``: the stretch's start (epoch s), so the closest moment reads as seconds into it. */
export function separationLines(sep, start) {
  if (!sep) return null;
  const c = sep.closest;
  const at = c && Number.isFinite(start) ? `, ${(c.ts - start).toFixed(1)} s in` : "";
  const closest = c
    ? `closest approach ${c.distance_m.toFixed(3)} m centre to centre (${c.robots.join(" and ")}${at})`
    : "closest approach: no two robots measured at the same time";
  const counts = `${plural(sep.violations, "violation")} (${sep.violation_s.toFixed(2)} s) under `
    + `${sep.min_separation_m.toFixed(2)} m, ${plural(sep.contacts, "contact")} (${sep.contact_s.toFixed(2)} s) `
    + `under ${sep.contact_m.toFixed(2)} m`;
  const near = sep.intervention_min_distance_m != null ? `, nearest reported ${sep.intervention_min_distance_m.toFixed(3)} m` : "";
  const filters = `${plural(sep.interventions, "safety filter intervention")} (${sep.intervention_s.toFixed(2)} s${near})`;
  return [closest, counts, filters];
}
