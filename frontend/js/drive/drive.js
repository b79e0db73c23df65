// Drive pad and keyboard driving. Hold to drive: the command is resent every 100 ms with duration_s 0.35,
// so a frozen tab, a killed browser, a dropped link or a closed laptop stops the robot within half a second
// (0.35 s of deadman leaves room for delivery and deceleration); release, blur, hiding the page or closing
// it sends an explicit stop. Driving needs the operator role.
import { api } from "../core/api.js";
import { controlReason } from "./control.js";
import { session } from "../core/session.js";
import { store } from "../core/store.js";
import { el, textFieldFocused } from "../core/util.js";

const RESEND_MS = 100;
const HOLD_DURATION_S = 0.35;
const KEYS = {
  ArrowUp: "move_forward", w: "move_forward", W: "move_forward",
  ArrowDown: "move_backward", s: "move_backward", S: "move_backward",
  ArrowLeft: "turn_left", a: "turn_left", A: "turn_left",
  ArrowRight: "turn_right", d: "turn_right", D: "turn_right",
};
const BUTTONS = [
  ["drive-forward", "move_forward", "▲", 2, 1],
  ["drive-left", "turn_left", "◀", 1, 2],
  ["drive-stop", "stop", "STOP", 2, 2],
  ["drive-right", "turn_right", "▶", 3, 2],
  ["drive-backward", "move_backward", "▼", 2, 3],
];

class Driver {
  constructor() {
    this.robotId = null;
    this.speed = 0.5;
    this.active = null; // {command, source, key?}
    this.timer = null;
    this.lastError = "";
    this.pads = new Set();
    this.sent = 0;
    const release = () => this.release();
    window.addEventListener("blur", release);
    window.addEventListener("pagehide", () => this.release(true));
    document.addEventListener("visibilitychange", () => document.hidden && release());
    window.addEventListener("keydown", (ev) => this.onKey(ev, true));
    window.addEventListener("keyup", (ev) => this.onKey(ev, false));
    store.on("robots", () => this.refresh());
    store.on("estop", () => this.refresh());
    store.on("connection", () => this.refresh());
    store.on("session", () => this.refresh());
    // a button press that ends anywhere (outside the pad, another window) still stops the robot
    window.addEventListener("pointerup", () => this.active?.key?.startsWith("button:") && this.release());
    window.addEventListener("pointercancel", () => this.active?.key?.startsWith("button:") && this.release());
  }

  setRobot(id) {
    if (id !== this.robotId) this.release();
    this.robotId = id;
    this.refresh();
  }

  reason() {
    return controlReason(this.robotId, "move_forward");
  }

  canDrive() {
    return this.reason() === "";
  }

  send(command, source, args, retries = command === "stop" ? 3 : 0) {
    const id = this.robotId;
    this.sent += 1;
    api.command(id, command, args, { ttl_s: 1.0, source }).then(
      () => {
        if (this.lastError) {
          this.lastError = "";
          this.refresh();
        }
      },
      (err) => {
        // a stop must get through: over the rate limit (429) or a blip, try again shortly
        if (retries > 0 && (err.status === 429 || err.status >= 500 || err.status === undefined)) {
          setTimeout(() => this.robotId === id && this.send(command, source, args, retries - 1), 150);
          return;
        }
        this.lastError = err.message;
        this.refresh();
      },
    );
  }

  hold(command, source, key) {
    if (command === "stop") return this.stop(source);
    if (!this.canDrive()) return;
    if (this.active && this.active.command === command && this.active.key === key) return;
    clearInterval(this.timer);
    this.active = { command, source, key };
    const tick = () => this.send(command, source, { speed: this.speed, duration_s: HOLD_DURATION_S });
    tick();
    this.timer = setInterval(tick, RESEND_MS);
    this.refresh();
  }

  release(closing = false) {
    if (!this.active) return;
    const { source } = this.active;
    clearInterval(this.timer);
    this.timer = null;
    this.active = null;
    if (closing && navigator.sendBeacon) {
      const body = JSON.stringify({ command: "stop", args: {}, ttl_s: 1.0, source });
      navigator.sendBeacon(`/api/robots/${encodeURIComponent(this.robotId)}/commands`,
        new Blob([body], { type: "application/json" }));
    } else {
      this.send("stop", source, {});
    }
    this.refresh();
  }

  stop(source) {
    clearInterval(this.timer);
    this.timer = null;
    this.active = null;
    if (this.robotId && store.robots.get(this.robotId)?.online && session.allows("operator")) this.send("stop", source, {});
    this.refresh();
  }

  onKey(ev, down) {
    if (ev.key === "Escape") return; // e-stop has its own handler
    if (!down && KEYS[ev.key] && this.active?.key === ev.key.toLowerCase()) {
      this.release(); // always, whatever has the focus now
      return;
    }
    if (textFieldFocused() || ev.ctrlKey || ev.metaKey || ev.altKey) return;
    // only where a drive pad is on screen (not on the history page)
    if (!this.robotId || ![...this.pads].some((pad) => pad.host.offsetParent !== null)) return;
    if (ev.key === " " || ev.code === "Space") {
      ev.preventDefault();
      if (down) this.stop("ui-keyboard");
      return;
    }
    const command = KEYS[ev.key];
    if (!command) return;
    ev.preventDefault();
    if (down) {
      if (!ev.repeat) this.hold(command, "ui-keyboard", ev.key.toLowerCase());
    } else if (this.active && this.active.key === ev.key.toLowerCase()) {
      this.release();
    }
  }

  refresh() {
    if (this.active && !this.canDrive()) {
      clearInterval(this.timer);
      this.timer = null;
      this.active = null;
    }
    for (const pad of this.pads) pad.render();
  }
}

export const driver = new Driver();

export class DrivePad {
  constructor(host) {
    this.host = host;
    this.buttons = new Map();
    const pad = el("div", { class: "pad" });
    for (const [testid, command, label, col, row] of BUTTONS) {
      const b = el("button", {
        type: "button", class: command === "stop" ? "stop" : "", "data-testid": testid, title: command.replace("_", " "),
        style: `grid-column:${col};grid-row:${row}`,
      }, label);
      if (command === "stop") {
        b.addEventListener("click", () => driver.stop("ui-button"));
      } else {
        b.addEventListener("pointerdown", (ev) => {
          if (ev.button !== 0) return;
          ev.preventDefault();
          // touch captures the pointer implicitly: undo that so sliding off the button stops the robot
          if (b.hasPointerCapture?.(ev.pointerId)) b.releasePointerCapture(ev.pointerId);
          driver.hold(command, "ui-button", `button:${command}`);
        });
        for (const type of ["pointerup", "pointercancel", "pointerleave"]) {
          b.addEventListener(type, () => {
            if (driver.active?.key === `button:${command}`) driver.release();
          });
        }
        b.addEventListener("contextmenu", (ev) => ev.preventDefault());
      }
      this.buttons.set(command, b);
      pad.append(b);
    }
    this.slider = el("input", { type: "range", min: "0.1", max: "1", step: "0.05", value: String(driver.speed),
      "data-testid": "speed-slider", "aria-label": "speed" });
    this.speedLabel = el("span", {}, `${Math.round(driver.speed * 100)} %`);
    this.slider.addEventListener("input", () => {
      driver.speed = Number(this.slider.value);
      this.speedLabel.textContent = `${Math.round(driver.speed * 100)} %`;
    });
    this.target = el("div", { class: "target", "data-testid": "drive-target" });
    this.reasonEl = el("div", { class: "reason", "data-testid": "drive-reason" });
    host.replaceChildren(el("section", { class: "drive" }, el("h3", {}, "Drive"), this.target, pad,
      el("label", { class: "speed" }, "Speed", this.slider, this.speedLabel), this.reasonEl,
      el("div", { class: "hint" }, "Hold a button, or arrows / WASD; space = stop; Esc = e-stop all.")));
    driver.pads.add(this);
    this.render();
  }

  render() {
    const reason = driver.reason();
    this.target.textContent = driver.robotId ?? "No robot selected";
    this.reasonEl.textContent = reason || driver.lastError;
    for (const [command, b] of this.buttons) {
      b.disabled = command === "stop" ? !driver.robotId || !session.allows("operator") : reason !== "";
      b.title = reason || command.replace("_", " ");
      b.classList.toggle("held", driver.active?.command === command);
    }
  }
}
