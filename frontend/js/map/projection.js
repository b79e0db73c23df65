// The pool map's projection: Lighthouse metres <-> CSS pixels in the map element, from the axes Plotly laid
// out (and, while the user drags, the ranges the drag has reached).

/** {px, py, x, y, clip} of the map element, or null before Plotly laid its axes out. */
export function projectionOf(mapEl, liveRanges) {
  const fl = mapEl._fullLayout;
  const xa = fl?.xaxis, ya = fl?.yaxis;
  if (!xa?._length || !ya?._length) return null;
  const [x0, x1] = liveRanges?.x ?? xa.range;
  const [y0, y1] = liveRanges?.y ?? ya.range;
  const kx = xa._length / (x1 - x0), ky = ya._length / (y1 - y0);
  return {
    px: (x) => xa._offset + (x - x0) * kx,
    py: (y) => ya._offset + (y1 - y) * ky,
    x: (px) => x0 + (px - xa._offset) / kx,
    y: (py) => y1 - (py - ya._offset) / ky,
    clip: [xa._offset, ya._offset, xa._length, ya._length],
  };
}

/** Axis ranges from a plotly_relayouting event (a drag in progress), keeping what it does not say. */
export function rangesFrom(ev, prev) {
  const pick = (ax) => {
    if (ev[`${ax}.range[0]`] !== undefined) return [ev[`${ax}.range[0]`], ev[`${ax}.range[1]`]];
    if (Array.isArray(ev[`${ax}.range`])) return ev[`${ax}.range`];
    return prev?.[ax] ?? null;
  };
  return { x: pick("xaxis"), y: pick("yaxis") };
}
