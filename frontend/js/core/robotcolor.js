// One colour per robot, from its id alone: the same robot has the same colour on the map, in the robot
// list and in every plot, on every page and after every reload, with no table to keep in step.

/** FNV-1a over the id's UTF-16 code units: small, stable, well spread. */
function hash(id) {
  let h = 0x811c9dc5;
  for (let i = 0; i < id.length; i++) {
    h ^= id.charCodeAt(i);
    h = Math.imul(h, 0x01000193) >>> 0;
  }
  return h;
}

/** The robot's hue in degrees: the hash stepped by the golden angle, so ids differing in one character
 * (snail-1, snail-2) land far apart on the colour wheel. */
export function robotHue(id) {
  return (hash(String(id)) * 137.508) % 360;
}

/** CSS colour of a robot (mid lightness: readable on the light and the dark theme). */
export function robotColor(id, alpha = 1) {
  const h = robotHue(id).toFixed(1);
  return alpha >= 1 ? `hsl(${h}, 70%, 48%)` : `hsla(${h}, 70%, 48%, ${alpha})`;
}
