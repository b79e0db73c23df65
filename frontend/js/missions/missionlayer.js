// The live missions on the fleet map, drawn under the robots' trails: each running or paused mission's plan
// (each robot's part: its polygon lightly filled and its path dashed, in the robot's colour) and the area its
// robots actually swept (green). All of it is what the server pushed on the live socket (store.js: the
// snapshot's missions and swept areas, then each `mission` and `mission_coverage`): nothing is polled and
// the browser never recomputes coverage from trails.
import { robotColor } from "../core/robotcolor.js";
import { store } from "../core/store.js";

const SWEPT_FILL = "rgba(80, 220, 140, 0.35)";
const PATH_DASH = [6, 5];

/** The polygons of a GeoJSON geometry, each a list of rings (the first its outline, the rest its holes). */
export function ringsOf(geom) {
  if (!geom || !geom.type) return [];
  if (geom.type === "Polygon") return [geom.coordinates];
  if (geom.type === "MultiPolygon") return geom.coordinates;
  if (geom.type === "GeometryCollection") return geom.geometries.flatMap(ringsOf);
  return [];
}

function tracePolygon(ctx, proj, rings) {
  ctx.beginPath();
  for (const ring of rings) {
    ring.forEach(([x, y], i) => (i ? ctx.lineTo(proj.px(x), proj.py(y)) : ctx.moveTo(proj.px(x), proj.py(y))));
    ctx.closePath();
  }
}

export class MissionLayer {
  /** ``map``: a FleetMap; its ``underlays`` draw this layer on every canvas pass. By default it shows every
   * running or paused mission and the swept areas the server pushed; the missions page passes ``shown`` (the
   * mission it works on, in any state) and ``sweptOf`` (its swept area, pushed or read once). */
  constructor(map, { source = store, shown = null, sweptOf = null } = {}) {
    this.map = map;
    this.source = source;
    this.pick = shown ?? (() => [...source.missions.values()].filter((m) => m.state === "running" || m.state === "paused"));
    this.sweptOf = sweptOf ?? ((id) => source.swept.get(id));
    this.id = "missions"; // a layer of the map (map/layers.js): switched off with its checkbox
    this.label = "mission plan and swept area";
    map.addLayer(this);
    source.on("missions", () => this.changed());
    this.describe();
  }

  /** Redraw (the missions page calls it when its own choice changed). */
  changed() {
    this.map.dirty = true;
    this.describe();
  }

  shown() {
    return this.pick();
  }

  /** What the layer holds, on the map element (data-mission-paths, data-mission-swept): for tests and tools. */
  describe() {
    const shown = this.shown();
    const paths = shown.reduce((n, m) => n + (m.parts ?? []).filter((p) => p.path.length > 1).length, 0);
    const swept = shown.reduce((n, m) => n + ringsOf(this.sweptOf(m.id)).length, 0);
    this.map.el.dataset.missionPaths = String(paths);
    this.map.el.dataset.missionSwept = String(swept);
  }

  draw(ctx, proj) {
    for (const m of this.shown()) {
      const parts = m.parts ?? [];
      ctx.save();
      for (const part of parts) {
        for (const ring of part.polygon) {
          tracePolygon(ctx, proj, [ring]);
          ctx.fillStyle = robotColor(part.robot_id, 0.1);
          ctx.fill();
        }
      }
      for (const rings of ringsOf(this.sweptOf(m.id))) {
        tracePolygon(ctx, proj, rings);
        ctx.fillStyle = SWEPT_FILL;
        ctx.fill("evenodd");
      }
      ctx.setLineDash(PATH_DASH);
      ctx.lineWidth = 1.5;
      for (const part of parts) {
        if (part.path.length < 2) continue;
        ctx.beginPath();
        part.path.forEach(([x, y], i) => (i ? ctx.lineTo(proj.px(x), proj.py(y)) : ctx.moveTo(proj.px(x), proj.py(y))));
        ctx.strokeStyle = robotColor(part.robot_id, 0.8);
        ctx.stroke();
      }
      ctx.restore();
    }
  }
}
