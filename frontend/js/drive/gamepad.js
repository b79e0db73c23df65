// A gamepad (the browser Gamepad API) drives the selected robot proportionally: left stick up/down is
// forward/backward, left stick left/right turns (the right stick's x axis turns too, for two-stick
// habits). The pads are polled every POLL_MS (the API has no "axis moved" event); a pad that disconnects
// or vanishes from navigator.getGamepads() counts as a centred stick, so the robot is stopped.
// Browsers expose a pad only after a button press on it (a privacy rule): the panel says so.
import { VelocityDrive } from "./velocity.js";

const POLL_MS = 50;

export class GamepadInput {
  constructor() {
    this.drive = new VelocityDrive("ui-gamepad");
    this.pad = null; // {index, id} of the pad in use
    window.addEventListener("gamepadconnected", () => this.poll());
    window.addEventListener("gamepaddisconnected", (ev) => {
      if (this.pad && ev.gamepad?.index === this.pad.index) this.lost();
    });
    setInterval(() => this.poll(), POLL_MS);
  }

  poll() {
    let pads = [];
    try {
      pads = [...(navigator.getGamepads?.() ?? [])];
    } catch {
      pads = []; // a permissions policy can forbid the API: no pad
    }
    const pad = pads.find((p) => p && p.connected !== false && (this.pad === null || p.index === this.pad.index))
      ?? pads.find((p) => p && p.connected !== false);
    if (!pad) {
      if (this.pad) this.lost();
      return;
    }
    if (this.pad?.index !== pad.index) {
      this.pad = { index: pad.index, id: pad.id };
      this.drive.changed();
    }
    const ax = pad.axes ?? [];
    const turnAxis = Math.abs(ax[0] ?? 0) >= Math.abs(ax[2] ?? 0) ? ax[0] : ax[2];
    this.drive.set(-(ax[1] ?? 0), -(turnAxis ?? 0)); // stick up is -1; stick left (-1) turns left (+)
  }

  lost() {
    this.pad = null;
    this.drive.set(0, 0); // centred: stops the robot now, the deadman would anyway
    this.drive.needNeutral = true;
    this.drive.changed();
  }

  status() {
    if (!this.pad) return "No gamepad: connect one and press any button on it.";
    return `Gamepad: ${this.pad.id.slice(0, 40)}`;
  }
}
