// Proportional driving for the stick inputs (the gamepad and the on-screen joystick): the stick's
// deflection becomes a `drive` command {linear, angular, duration_s}, repeated every SEND_MS while the
// stick is off centre. duration_s is the deadman: the robot stops by itself DEADMAN_S after the last
// command that reached it, so a frozen tab, a lost link or a closed laptop stops it; centring the stick,
// disconnecting the gamepad, hiding or leaving the page also send an explicit stop.
// Safety latch: whenever driving is refused (e-stop, hold, offline, another robot selected, page hidden
// or unfocused) the input must come back to centre before it drives again, so releasing an e-stop with the
// stick still pushed never sets the robot off by itself.
import { api } from "../core/api.js";
import { controlReason } from "./control.js";
import { driver } from "./drive.js";
import { store } from "../core/store.js";

export const SEND_MS = 80; // 12.5 Hz
export const DEADMAN_S = 0.3;
/** Full stick at 100 % speed (the drive pad's speed slider scales it); the robot clamps to its own limits. */
export const MAX_LINEAR_MPS = 0.2;
export const MAX_ANGULAR_RPS = 1.5;
/** Deflections under this (of 1) are centre: a worn gamepad stick never rests exactly at 0. */
export const NEUTRAL = 0.15;

export class VelocityDrive {
  /** ``source`` names the commands in the log ("ui-gamepad", "ui-joystick"). */
  constructor(source) {
    this.source = source;
    this.robotId = null;
    this.input = { forward: 0, turn: 0 };
    this.needNeutral = true; // a stick already pushed when the page opens does not drive
    this.timer = null;
    this.sent = 0;
    this.stops = 0;
    this.lastError = "";
    this.visible = () => true; // set by the view that shows it: no driving from a page without the stick
    this.listeners = new Set();
    const update = () => this.apply();
    for (const topic of ["robots", "estop", "connection", "session"]) store.on(topic, update);
    document.addEventListener("visibilitychange", () => document.hidden && this.block());
    // an unfocused page may keep reading a gamepad's last state: stop rather than drive on a stale stick
    window.addEventListener("blur", () => this.block());
    window.addEventListener("pagehide", () => this.block());
  }

  get active() {
    return this.timer !== null;
  }

  /** Why the stick cannot drive now ("" when it can). */
  reason() {
    const why = controlReason(driver.robotId, "drive");
    if (why) return why;
    if (!this.visible()) return "Open the fleet page to drive with the stick.";
    if (this.needNeutral) return "Return the stick to centre to drive.";
    return "";
  }

  /** A new stick reading: forward and turn (counter-clockwise) in -1..1. */
  set(forward, turn) {
    this.input = { forward: clamp(forward), turn: clamp(turn) };
    this.apply();
  }

  neutral() {
    return Math.hypot(this.input.forward, this.input.turn) < NEUTRAL;
  }

  apply() {
    if (driver.robotId !== this.robotId) {
      if (this.active) this.stop();
      this.robotId = driver.robotId;
      this.needNeutral = true; // pushing the stick for one robot never drives the next one selected
    }
    const blocked = controlReason(this.robotId, "drive") || (this.visible() ? "" : "hidden");
    if (blocked) {
      if (this.active) this.halt(); // refused anyway (the e-stop already stopped it); no more drives
      this.needNeutral = true;
    } else if (this.neutral()) {
      if (this.needNeutral) this.lastError = ""; // a fresh start: refusals from before the latch are old news
      this.needNeutral = false;
      if (this.active) this.stop();
    } else if (!this.needNeutral && !this.active) {
      this.tick();
      this.timer = setInterval(() => this.tick(), SEND_MS);
    }
    this.changed();
  }

  /** The command for the stick as it is now. */
  velocity() {
    const scale = driver.speed;
    const shape = (v) => Math.sign(v) * Math.max(0, (Math.abs(v) - NEUTRAL) / (1 - NEUTRAL)); // no jump at the edge
    return {
      linear: round(shape(this.input.forward) * MAX_LINEAR_MPS * scale),
      angular: round(shape(this.input.turn) * MAX_ANGULAR_RPS * scale),
    };
  }

  tick() {
    if (driver.active) return; // a held drive button or key has the robot: it wins while held
    this.send("drive", { ...this.velocity(), duration_s: DEADMAN_S });
  }

  /** Stop sending; the deadman stops the robot. */
  halt() {
    clearInterval(this.timer);
    this.timer = null;
  }

  /** Stop sending and tell the robot to stop now. */
  stop() {
    this.halt();
    this.stops += 1;
    if (this.robotId) this.send("stop", {}, 3);
  }

  /** The page goes away or hides: stop, and demand centre before driving again. */
  block() {
    if (this.active) this.stop();
    this.needNeutral = true;
    this.changed();
  }

  send(command, args, retries = 0) {
    const id = this.robotId;
    this.sent += command === "drive" ? 1 : 0;
    api.command(id, command, args, { ttl_s: 1.0, source: this.source }).then(
      () => {
        if (this.lastError) {
          this.lastError = "";
          this.changed();
        }
      },
      (err) => {
        if (retries > 0 && (err.status === 429 || err.status >= 500 || err.status === undefined)) {
          setTimeout(() => this.robotId === id && this.send(command, args, retries - 1), 150);
          return;
        }
        this.lastError = err.message;
        this.changed();
      },
    );
  }

  onChange(fn) {
    this.listeners.add(fn);
  }

  changed() {
    for (const fn of this.listeners) fn();
  }

  /** For the page's debug hook and tests. */
  state() {
    return { robot: this.robotId, active: this.active, needNeutral: this.needNeutral, sent: this.sent,
      stops: this.stops, input: { ...this.input }, reason: this.reason() };
  }
}

function clamp(v) {
  return Number.isFinite(v) ? Math.max(-1, Math.min(1, v)) : 0;
}

function round(v) {
  return Math.round(v * 1000) / 1000;
}
