// The pool map's layers, each of which can be switched off: the site (boundary, keep-outs, wall tags), the base
// stations and tags seen, the robots' trails and the robots, and the layers other rooms add (a mission's plan
// and swept area, the goals and paths of Go-to, a replay's coverage and comparison, the selected robot's safety
// distance). A layer is an object with an ``id``, a ``label`` and ``draw(ctx, proj)`` (proj: metres <-> CSS
// pixels), and ``off: true`` to start unchecked, added with ``map.addLayer(layer)`` (under the robots, or
// ``{ over: true }``): one file and one line. One without an id (an editor's drawing) is always drawn. The
// scale bar is drawn last, always.
import { el } from "../core/util.js";

/** The layers of every map, drawn by the map itself. */
export const BUILT_IN = [
  { id: "site", label: "site" },
  { id: "stations", label: "base stations and tags" },
  { id: "trails", label: "trails" },
  { id: "robots", label: "robots" },
];
/** Scale bar lengths (m) to choose from: the one nearest 90 px. */
const SCALE_STEPS_M = [0.05, 0.1, 0.2, 0.25, 0.5, 1, 2, 5, 10, 20, 50];
const SCALE_TARGET_PX = 90;

/** "Layers": a checkbox per layer that has an id (data-testid="map-layer-<id>"), in a collapsed panel that
 * floats in the map's bottom-left corner (under the y axis: axis labels, not the pool), so that it never moves
 * the page's layout nor takes a click meant for the pool. */
export class LayerToggles {
  constructor(map) {
    this.map = map;
    this.hidden = new Set();
    this.list = el("div", { class: "map-layers-list", role: "group", "aria-label": "Map layers" });
    this.row = el("details", { class: "map-layers", "data-testid": "map-layers" },
      el("summary", { "data-testid": "map-layers-summary" }, "Layers"), this.list);
    this.render();
  }

  /** Put it over the map (after Plotly's first plot, which replaces the map element's children). */
  attach() {
    this.map.el.appendChild(this.row);
  }

  /** True for an event inside the panel: the map neither takes it as a click on the pool nor selects. */
  owns(ev) {
    return this.row.contains(ev.target);
  }

  shows(id) {
    return id == null || !this.hidden.has(id);
  }

  set(id, on) {
    if (on) this.hidden.delete(id);
    else this.hidden.add(id);
    this.map.staticDirty = this.map.dirty = true;
    this.render();
  }

  render() {
    const layers = [...BUILT_IN, ...this.map.underlays, ...this.map.overlays].filter((l) => l.id && l.label);
    this.list.replaceChildren(...layers.map((l) => el("label", { class: "toggle" },
      el("input", { type: "checkbox", checked: this.shows(l.id), "data-testid": `map-layer-${l.id}`,
        onchange: (ev) => this.set(l.id, ev.target.checked) }), ` ${l.label}`)));
  }
}

/** A bar of a round length in the plot's bottom-left corner, labelled in metres. */
export function drawScaleBar(ctx, proj, color) {
  const perMetre = Math.abs(proj.px(1) - proj.px(0));
  if (!(perMetre > 0)) return;
  const metres = SCALE_STEPS_M.reduce((best, m) =>
    (Math.abs(m * perMetre - SCALE_TARGET_PX) < Math.abs(best * perMetre - SCALE_TARGET_PX) ? m : best));
  const [left, top, , height] = proj.clip;
  const x = left + 12, y = top + height - 14, w = metres * perMetre;
  ctx.save();
  ctx.strokeStyle = ctx.fillStyle = color;
  ctx.lineWidth = 2;
  ctx.beginPath();
  ctx.moveTo(x, y - 5);
  ctx.lineTo(x, y);
  ctx.lineTo(x + w, y);
  ctx.lineTo(x + w, y - 5);
  ctx.stroke();
  ctx.font = "11px system-ui, sans-serif";
  ctx.textAlign = "center";
  ctx.textBaseline = "bottom";
  ctx.fillText(metres >= 1 ? `${metres} m` : `${Math.round(metres * 100)} cm`, x + w / 2, y - 3);
  ctx.restore();
  return metres;
}
