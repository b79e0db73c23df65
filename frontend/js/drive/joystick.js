// The on-screen joystick (touch, pen or mouse, through pointer events) and the stick panel under the drive
// pad: the joystick, the gamepad's state and why the stick cannot drive (inline, never only a tooltip).
// The knob follows the finger within the ring; lifting the finger, the pointer being cancelled (a
// system gesture) or leaving the page centres it, which stops the robot (velocity.js).
import { controlReason } from "./control.js";
import { driver } from "./drive.js";
import { GamepadInput } from "./gamepad.js";
import { VelocityDrive } from "./velocity.js";
import { el } from "../core/util.js";

export class StickPanel {
  constructor(host) {
    this.host = host;
    this.drive = new VelocityDrive("ui-joystick");
    this.gamepad = new GamepadInput();
    const visible = () => host.offsetParent !== null;
    this.drive.visible = visible;
    this.gamepad.drive.visible = visible;
    this.knob = el("div", { class: "stick-knob" });
    this.ring = el("div", {
      class: "stick", "data-testid": "joystick", role: "application", tabindex: "-1",
      "aria-label": "Joystick: drag to drive, up is forward; let go to stop (touch or mouse)",
    }, this.knob);
    this.reasonEl = el("div", { class: "reason", "data-testid": "stick-reason" });
    this.padEl = el("div", { class: "hint", "data-testid": "gamepad-status" });
    host.replaceChildren(el("section", { class: "drive stick-panel" },
      el("h3", {}, "Stick"), this.ring, this.reasonEl, this.padEl,
      el("div", { class: "hint" }, "Drag the joystick or use a gamepad's left stick; let go to stop.")));
    this.pointer = null;
    this.origin = null;
    this.ring.addEventListener("pointerdown", (ev) => this.down(ev));
    this.ring.addEventListener("pointermove", (ev) => this.move(ev));
    for (const type of ["pointerup", "pointercancel", "lostpointercapture"]) this.ring.addEventListener(type, (ev) => this.up(ev));
    this.ring.addEventListener("contextmenu", (ev) => ev.preventDefault());
    window.addEventListener("blur", () => this.release());
    this.drive.onChange(() => this.render());
    this.gamepad.drive.onChange(() => this.render());
    setInterval(() => {
      this.drive.apply(); // the selection, the e-stop and the view change without a stick event
      this.render();
    }, 250);
    this.render();
  }

  down(ev) {
    if (ev.button !== 0 && ev.pointerType === "mouse") return;
    ev.preventDefault();
    this.pointer = ev.pointerId;
    this.ring.setPointerCapture?.(ev.pointerId);
    // the centre is where the ring was when the finger came down: a page that moves under a held finger (an
    // alarm banner appearing above) must not move the stick by itself (a test saw 0.9 become 0.05 so)
    const r = this.ring.getBoundingClientRect();
    this.origin = { x: r.left + r.width / 2, y: r.top + r.height / 2, radius: r.width / 2 };
    this.move(ev);
  }

  move(ev) {
    if (ev.pointerId !== this.pointer || !this.origin) return;
    const { x, y, radius } = this.origin;
    let dx = (ev.clientX - x) / radius, dy = (ev.clientY - y) / radius;
    const len = Math.hypot(dx, dy);
    if (len > 1) [dx, dy] = [dx / len, dy / len];
    this.knob.style.transform = `translate(${dx * radius * 0.7}px, ${dy * radius * 0.7}px)`;
    this.drive.set(-dy, -dx);
  }

  up(ev) {
    if (ev.pointerId === this.pointer) this.release();
  }

  release() {
    this.pointer = null;
    this.origin = null;
    this.knob.style.transform = "";
    this.drive.set(0, 0);
  }

  render() {
    const js = this.drive, gp = this.gamepad.drive;
    const blocked = controlReason(driver.robotId, "drive");
    let text = blocked;
    if (!text && this.gamepad.pad && gp.needNeutral && !gp.neutral()) text = "Return the gamepad stick to centre to drive.";
    if (!text && js.needNeutral && !js.neutral()) text = "Return the joystick to centre to drive.";
    text ||= js.lastError || gp.lastError;
    if (this.reasonEl.textContent !== text) this.reasonEl.textContent = text;
    const pad = this.gamepad.status();
    if (this.padEl.textContent !== pad) this.padEl.textContent = pad;
    this.ring.classList.toggle("driving", js.active || gp.active);
    this.ring.classList.toggle("blocked", blocked !== "");
  }

  state() {
    return { joystick: this.drive.state(), gamepad: { ...this.gamepad.drive.state(), pad: this.gamepad.pad } };
  }
}
