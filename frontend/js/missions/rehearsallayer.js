// A rehearsal's predicted tracks on the missions page's map: one line per robot, in the robot's own colour
// (core/robotcolor.js, as the map draws the robot itself), dotted and lighter than the plan's dashed paths
// and the live trails, so that it reads as a prediction, never as where a robot went. It is a layer of the map
// (map/layers.js: "predicted tracks" in its Layers panel), drawn under the robots; the missions page sets it
// from a rehearsal's answer and clears it when the mission is closed or another one is opened.
import { robotColor } from "../core/robotcolor.js";

// round caps turn these into dots: unlike the plan's dashes (missionlayer.js) and the trails' solid lines
const DOTS = [0.5, 6];
const ALPHA = 0.75;
const WIDTH_PX = 3;
const END_RADIUS_PX = 4;
const CAPTION = "··· predicted (rehearsal)";

/** The LineString features of a GeoJSON FeatureCollection as {robotId, points}. */
export function tracksOf(collection) {
  return (collection?.features ?? [])
    .filter((f) => f?.geometry?.type === "LineString" && f.geometry.coordinates.length > 1)
    .map((f) => ({ robotId: String(f.properties?.robot_id ?? ""), points: f.geometry.coordinates }));
}

export class PredictedLayer {
  constructor(map) {
    this.map = map;
    this.id = "predicted"; // a layer of the map: switched off with its checkbox
    this.label = "predicted tracks (rehearsal)";
    this.tracks = [];
    this.drawn = []; // what the last pass drew: {robotId, color, points} (tests, window.fleetDebug)
    map.addLayer(this);
    this.describe();
  }

  /** The tracks of a rehearsal's answer (``predicted.tracks``); null clears the layer. */
  set(collection) {
    this.tracks = tracksOf(collection);
    this.drawn = [];
    this.map.dirty = true;
    this.describe();
  }

  /** How many tracks the layer holds, on the map element (data-predicted-tracks): for tests and tools. */
  describe() {
    this.map.el.dataset.predictedTracks = String(this.tracks.length);
  }

  draw(ctx, proj) {
    const drawn = [];
    if (!this.tracks.length) {
      this.drawn = drawn;
      return;
    }
    ctx.save();
    ctx.lineWidth = WIDTH_PX;
    ctx.lineCap = "round";
    ctx.lineJoin = "round";
    for (const { robotId, points } of this.tracks) {
      const color = robotColor(robotId, ALPHA);
      ctx.setLineDash(DOTS);
      ctx.beginPath();
      points.forEach(([x, y], i) => (i ? ctx.lineTo(proj.px(x), proj.py(y)) : ctx.moveTo(proj.px(x), proj.py(y))));
      ctx.strokeStyle = color;
      ctx.stroke();
      // where the robot is predicted to end: a hollow ring, unlike the robot's filled marker
      const [ex, ey] = points[points.length - 1];
      ctx.setLineDash([]);
      ctx.lineWidth = 1.5;
      ctx.beginPath();
      ctx.arc(proj.px(ex), proj.py(ey), END_RADIUS_PX, 0, 2 * Math.PI);
      ctx.stroke();
      ctx.lineWidth = WIDTH_PX;
      drawn.push({ robotId, color, points: points.length });
    }
    this.caption(ctx, proj);
    ctx.restore();
    this.drawn = drawn;
  }

  /** "predicted" in the plot's bottom-right corner (the scale bar has the left one), while tracks are drawn. */
  caption(ctx, proj) {
    const [left, top, width, height] = proj.clip;
    const right = left + width - 8, bottom = top + height - 6;
    ctx.font = "11px system-ui, sans-serif";
    ctx.textAlign = "right";
    ctx.textBaseline = "bottom";
    // on the panel's colour: readable over the pool's outline or a track running under it
    const w = ctx.measureText(CAPTION).width;
    ctx.globalAlpha = 0.85;
    ctx.fillStyle = this.map.colors?.bg || "#fff";
    ctx.fillRect(right - w - 3, bottom - 14, w + 6, 16);
    ctx.globalAlpha = 1;
    ctx.fillStyle = this.map.colors?.fg || "#888";
    ctx.fillText(CAPTION, right, bottom);
  }
}
