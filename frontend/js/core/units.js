// Units of telemetry fields, from the server's one table (GET /api/units, fleet_protocol/units.py).
import { api } from "./api.js";

let table = null;
let loading = null;

/** Loads the table once (later calls reuse it); on failure every unit is unknown. */
export function loadUnits() {
  loading ??= api.get("/api/units").then((body) => (table = body.streams ?? {}), () => (table = {}));
  return loading;
}

/** The unit of a field path (x, accel[0], tag3.euler_deg.yaw), "" if dimensionless, null if unknown:
 * the same lookup as fleet_protocol.units.unit_of. */
export function unitOf(stream, field) {
  const t = table?.[stream];
  if (!t) return null;
  let path = field.replace(/\[\d+\]/g, "");
  for (const suffix of ["_min", "_max"]) {
    if (path.endsWith(suffix) && !(path in t) && path.slice(0, -suffix.length) in t) path = path.slice(0, -suffix.length);
  }
  const parts = path.split(".");
  for (let first = 0; first < parts.length; first++) {
    for (let n = parts.length; n > first; n--) {
      const unit = t[parts.slice(first, n).join(".")];
      if (unit !== undefined) return unit;
    }
  }
  return null;
}
