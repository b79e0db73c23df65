// "Edit boundary" on the fleet map (admins): the site's boundary corners become handles on the map that a
// mouse, a pen or a finger drags (pointer events), and that the keyboard moves (arrows: 1 cm, Shift: 10 cm).
// A "+" handle in the middle of each edge adds a corner there (click it, or drag it out); a double click on a
// corner, Delete/Backspace on the focused corner, or "Remove corner" removes the selected one (three stay).
// The draft is drawn over the map as a preview (solid line) while the site in force stays drawn (dotted).
// Save sends the whole site with PUT /api/site, keep-outs, tags, base stations and margins as they were: the
// server decides. Its 422 (a boundary that crosses itself: bad_polygon; a keep-out left outside:
// keepout_outside_boundary) is shown with its code and the draft stays for a fix; nothing changed on the
// server. Cancel (or Esc, which also presses the fleet E-STOP as everywhere) drops the draft.
// While editing, a click on the map neither selects nor moves a robot (Go-to is disarmed and its buttons
// disabled), and keys pressed on a handle never reach the drive pad.
// Coordinates: the map's own projection (FleetMap.projection / toMap), never a copy of it.
import { api } from "../core/api.js";
import { session } from "../core/session.js";
import { store } from "../core/store.js";
import { themeColors } from "../core/theme.js";
import { el } from "../core/util.js";
import { MAX_CORNERS, MIN_CORNERS, selfCrossing, siteUpdate } from "./polygon.js";

const KEY_STEP_M = 0.01;
const KEY_STEP_BIG_M = 0.1;
/** A press that moves less than this is a click (select), not a drag: a click never moves a corner. */
const DRAG_START_PX = 3;

const round = (v) => Math.round(v * 1000) / 1000; // millimetres: the draft shows what is sent
const fmt = (p) => `(${p[0].toFixed(2)}, ${p[1].toFixed(2)})`;

export class BoundaryEditor {
  /** ``onStart()``/``onEnd()``: editing begins (Go-to disarms) or ends; ``onSaved(site)``: the new site
   * (GET /api/site's shape). */
  constructor(host, fleetMap, { onStart, onEnd, onSaved } = {}) {
    this.map = fleetMap;
    this.onStart = onStart ?? (() => {});
    this.onEnd = onEnd ?? (() => {});
    this.onSaved = onSaved ?? (() => {});
    this.base = null; // GET /api/site as it was when editing began (null: not editing)
    this.draft = []; // [[x, y]] the boundary being edited
    this.selected = null; // index of the selected corner
    this.drag = null; // {index, pointerId, x0, y0, from: [x, y], moved}
    this.saving = false;
    this.saves = 0;
    this.toggle = el("button", { type: "button", class: "btn", "data-testid": "boundary-edit",
      "aria-pressed": "false", title: "Drag the pool boundary's corners on the map, add or remove corners, then save" },
    "Edit boundary");
    this.saveBtn = el("button", { type: "button", class: "btn primary", "data-testid": "boundary-save" }, "Save boundary");
    this.cancelBtn = el("button", { type: "button", class: "btn", "data-testid": "boundary-cancel",
      title: "Drop the changes (Esc too, which also presses the E-STOP)" }, "Cancel");
    this.removeBtn = el("button", { type: "button", class: "btn", "data-testid": "boundary-remove" }, "Remove corner");
    this.status = el("span", { role: "status", "data-testid": "boundary-status" });
    this.error = el("span", { class: "site-error", role: "alert", "data-testid": "boundary-error" });
    this.hint = el("span", { class: "bad", "data-testid": "boundary-hint" });
    this.bar = el("div", { class: "boundary-bar", role: "group", "aria-label": "Edit the pool boundary on the map" },
      this.toggle, this.saveBtn, this.removeBtn, this.cancelBtn);
    this.notes = el("div", { class: "boundary-notes", "data-testid": "boundary-notes" },
      this.status, this.hint, this.error);
    host.append(this.bar, this.notes);
    this.toggle.addEventListener("click", () => (this.active ? this.cancel() : this.start()));
    this.saveBtn.addEventListener("click", () => this.save());
    this.cancelBtn.addEventListener("click", () => this.cancel());
    this.removeBtn.addEventListener("click", () => this.remove(this.selected));
    // the handles: one layer over the map's plot, above its live canvas; created once the map is drawn
    this.layer = el("div", { class: "boundary-layer", "data-testid": "boundary-layer" });
    this.layer.addEventListener("pointerdown", (ev) => this.pointerDown(ev));
    this.layer.addEventListener("dblclick", (ev) => this.doubleClick(ev));
    this.layer.addEventListener("click", (ev) => this.handleClick(ev));
    this.layer.addEventListener("keydown", (ev) => this.handleKey(ev));
    this.onMove = (ev) => this.pointerMove(ev);
    this.onUp = (ev) => this.pointerUp(ev, ev.type === "pointercancel");
    // Esc presses the fleet E-STOP (estop.js, never taken from it); an edit under way is dropped as well
    window.addEventListener("keydown", (ev) => ev.key === "Escape" && this.active && this.cancel("Esc"));
    store.on("session", () => this.render());
    fleetMap.overlays.add(this);
    this.render();
  }

  get active() {
    return this.base !== null;
  }

  isAdmin() {
    return session.me?.role === "admin";
  }

  async start() {
    if (this.active || !this.isAdmin()) return;
    this.say("", "");
    let site;
    try {
      site = await api.get("/api/site"); // the newest version, not the one the page loaded with
    } catch (err) {
      this.say("", `site not loaded: ${err.message}`);
      return;
    }
    if (!site.configured || !Array.isArray(site.boundary) || site.boundary.length < MIN_CORNERS) {
      this.say("", "There is no site (no fence): set one with Edit site first.");
      return;
    }
    if (!this.map.ready) {
      this.say("", "The map is not drawn yet: try again in a moment.");
      return;
    }
    this.base = site;
    this.draft = site.boundary.map((p) => [p[0], p[1]]);
    this.selected = null;
    this.map.editing = this;
    if (this.layer.parentNode !== this.map.el) this.map.el.appendChild(this.layer);
    this.onStart();
    this.say(`Editing site v${site.version}'s boundary: drag a corner, + adds one, double-click or Delete removes one.`);
    this.changed(true);
  }

  /** Drop the draft: nothing was sent, the site in force stays drawn. */
  cancel(how = "") {
    if (!this.active) return;
    this.end();
    this.say(`Boundary edit cancelled${how ? ` (${how})` : ""}: nothing changed.`, "");
  }

  end() {
    this.stopDrag();
    this.base = null;
    this.draft = [];
    this.selected = null;
    if (this.map.editing === this) this.map.editing = null;
    this.layer.replaceChildren();
    this.layer.remove();
    this.map.dirty = true;
    this.render();
    this.onEnd();
  }

  async save() {
    if (!this.active || this.saving) return;
    this.saving = true;
    this.say("Saving…", "");
    this.render();
    try {
      // another admin may have changed the site since: saving would silently undo their change
      const now = await api.get("/api/site");
      if (now.version !== this.base.version) {
        this.say("", `The site changed while you edited (now v${now.version}, by ${now.updated_by}): `
          + "your boundary was not saved. Cancel and edit again.");
        return;
      }
      this.saves += 1;
      const site = await api.put("/api/site", siteUpdate(this.draft, this.base));
      this.end();
      this.say(`Boundary saved as site v${site.version}.`, "");
      this.onSaved(site);
    } catch (err) {
      // the server's own words (and code): the draft stays for a fix, the site in force is unchanged
      this.say("", `Not saved: ${err.message}${err.code ? ` (${err.code})` : ""}. The site in force is unchanged.`);
    } finally {
      this.saving = false;
      this.render();
    }
  }

  // -- changing the draft -------------------------------------------------------------------------------------
  insert(edge, at) {
    if (this.draft.length >= MAX_CORNERS) {
      this.say("", `A boundary has at most ${MAX_CORNERS} corners.`);
      return null;
    }
    const i = edge + 1;
    this.draft.splice(i, 0, at);
    this.selected = i;
    this.changed(true);
    return i;
  }

  remove(i) {
    if (!this.active || i == null || i >= this.draft.length) return;
    if (this.draft.length <= MIN_CORNERS) {
      this.say("", `A boundary keeps at least ${MIN_CORNERS} corners.`);
      return;
    }
    this.draft.splice(i, 1);
    this.selected = this.draft.length ? Math.min(i, this.draft.length - 1) : null;
    this.changed(true);
    this.focusCorner(this.selected);
  }

  moveTo(i, x, y) {
    this.draft[i] = [round(x), round(y)];
    this.changed(false);
  }

  /** A change of the draft: redraw; ``rebuild`` when corners came or went (the handles are laid out again). */
  changed(rebuild) {
    if (rebuild) this.buildHandles();
    this.map.dirty = true;
    this.render();
  }

  // -- the handles ----------------------------------------------------------------------------------------------
  buildHandles() {
    const n = this.draft.length;
    const nodes = [];
    for (let i = 0; i < n; i++) {
      nodes.push(el("button", { type: "button", class: "bnd-corner", "data-index": String(i), hidden: true,
        "data-testid": `boundary-corner-${i}` }));
      nodes.push(el("button", { type: "button", class: "bnd-mid", "data-edge": String(i), hidden: true,
        "data-testid": `boundary-add-${i}`, "aria-label": `Add a corner between corners ${i + 1} and ${(i + 1) % n + 1}`,
        title: "Add a corner here (click, or drag it out)" }, "+"));
    }
    this.layer.replaceChildren(...nodes);
    this.placeHandles(this.map.projection()); // at once: a new corner takes the focus before the next frame
    this.labelHandles();
  }

  /** Names say where each corner is (updated when a move ends, not at every pointer move). */
  labelHandles() {
    const n = this.draft.length;
    for (const b of this.layer.querySelectorAll(".bnd-corner")) {
      const i = Number(b.dataset.index);
      const p = this.draft[i];
      if (!p) continue;
      b.setAttribute("aria-label", `Boundary corner ${i + 1} of ${n} at ${fmt(p)} m: drag or arrow keys move it, Delete removes it`);
      b.classList.toggle("selected", i === this.selected);
    }
  }

  focusCorner(i) {
    if (i == null) return;
    this.layer.querySelector(`.bnd-corner[data-index="${i}"]`)?.focus({ preventScroll: true });
  }

  handleAt(ev) {
    return ev.target instanceof Element ? ev.target.closest(".bnd-corner, .bnd-mid") : null;
  }

  pointerDown(ev) {
    const h = this.handleAt(ev);
    if (!h || !this.active || ev.button > 0) return;
    ev.preventDefault(); // no text selection, no focus flicker; the map's Plotly drag never sees it
    ev.stopPropagation();
    let index;
    if (h.classList.contains("bnd-mid")) {
      const e = Number(h.dataset.edge);
      const a = this.draft[e], b = this.draft[(e + 1) % this.draft.length];
      index = this.insert(e, [round((a[0] + b[0]) / 2), round((a[1] + b[1]) / 2)]);
      if (index == null) return;
    } else {
      index = Number(h.dataset.index);
      this.selected = index;
      this.labelHandles();
      this.render();
    }
    this.focusCorner(index);
    this.drag = { index, pointerId: ev.pointerId, x0: ev.clientX, y0: ev.clientY, from: [...this.draft[index]], moved: false };
    window.addEventListener("pointermove", this.onMove);
    window.addEventListener("pointerup", this.onUp);
    window.addEventListener("pointercancel", this.onUp);
  }

  pointerMove(ev) {
    const d = this.drag;
    if (!d || ev.pointerId !== d.pointerId) return;
    if (!d.moved && Math.hypot(ev.clientX - d.x0, ev.clientY - d.y0) < DRAG_START_PX) return;
    d.moved = true;
    ev.preventDefault();
    const at = this.map.toMap(ev, { clamp: true }); // held inside the plot: a corner never leaves the view
    if (at) this.moveTo(d.index, at.x, at.y);
  }

  pointerUp(ev, cancelled) {
    const d = this.drag;
    if (!d || ev.pointerId !== d.pointerId) return;
    if (cancelled && d.moved) this.moveTo(d.index, ...d.from); // the system took the pointer: undo the move
    this.stopDrag();
    this.labelHandles();
    if (d.moved) this.say(`Corner ${d.index + 1} at ${fmt(this.draft[d.index])} m.`);
  }

  stopDrag() {
    this.drag = null;
    window.removeEventListener("pointermove", this.onMove);
    window.removeEventListener("pointerup", this.onUp);
    window.removeEventListener("pointercancel", this.onUp);
  }

  doubleClick(ev) {
    const h = this.handleAt(ev);
    if (!h) return;
    ev.preventDefault();
    if (h.classList.contains("bnd-corner")) this.remove(Number(h.dataset.index));
  }

  /** Keyboard activation (a click with no pointer: detail 0): + adds its corner, a corner is selected. */
  handleClick(ev) {
    const h = this.handleAt(ev);
    if (!h || ev.detail !== 0) return;
    if (h.classList.contains("bnd-mid")) {
      const e = Number(h.dataset.edge);
      const a = this.draft[e], b = this.draft[(e + 1) % this.draft.length];
      const i = this.insert(e, [round((a[0] + b[0]) / 2), round((a[1] + b[1]) / 2)]);
      this.focusCorner(i);
    } else {
      this.selected = Number(h.dataset.index);
      this.labelHandles();
      this.render();
    }
  }

  /** On a focused corner: arrows move it, Delete/Backspace removes it. These keys stop here: with a handle
   * focused the arrows never drive the selected robot. */
  handleKey(ev) {
    const h = this.handleAt(ev);
    if (!h || !h.classList.contains("bnd-corner") || ev.key === "Escape") return;
    const i = Number(h.dataset.index);
    const step = ev.shiftKey ? KEY_STEP_BIG_M : KEY_STEP_M;
    const dir = { ArrowLeft: [-1, 0], ArrowRight: [1, 0], ArrowUp: [0, 1], ArrowDown: [0, -1] }[ev.key];
    if (dir) {
      const [x, y] = this.draft[i];
      this.selected = i;
      this.moveTo(i, x + dir[0] * step, y + dir[1] * step);
      this.labelHandles();
    } else if (ev.key === "Delete" || ev.key === "Backspace") {
      this.remove(i);
    } else {
      return;
    }
    ev.preventDefault();
    ev.stopPropagation();
  }

  // -- drawing ------------------------------------------------------------------------------------------------
  /** The map's live layer (FleetMap.overlays): the draft as a preview, and the handles placed on it. */
  draw(ctx, proj) {
    if (!this.active || this.draft.length < 2) return;
    const c = themeColors();
    const crossing = selfCrossing(this.draft);
    ctx.save();
    ctx.strokeStyle = crossing ? c.bad : c.accent;
    ctx.fillStyle = crossing ? c.bad : c.accent;
    ctx.lineWidth = 2;
    ctx.beginPath();
    this.draft.forEach(([x, y], i) => (i ? ctx.lineTo(proj.px(x), proj.py(y)) : ctx.moveTo(proj.px(x), proj.py(y))));
    ctx.closePath();
    ctx.globalAlpha = 0.1;
    ctx.fill();
    ctx.globalAlpha = 1;
    ctx.stroke();
    ctx.restore();
    this.placeHandles(proj);
  }

  /** Each handle over its corner (or its edge's middle), in the map's pixels; hidden when zoomed out of view. */
  placeHandles(proj) {
    if (!proj) return;
    const [l, t, w, h] = proj.clip;
    const place = (node, x, y) => {
      const px = proj.px(x), py = proj.py(y);
      node.hidden = px < l - 1 || px > l + w + 1 || py < t - 1 || py > t + h + 1;
      node.style.left = `${px}px`;
      node.style.top = `${py}px`;
    };
    const n = this.draft.length;
    for (const node of this.layer.children) {
      if (node.dataset.index !== undefined) {
        const p = this.draft[Number(node.dataset.index)];
        if (p) place(node, p[0], p[1]);
      } else {
        const e = Number(node.dataset.edge);
        const a = this.draft[e], b = this.draft[(e + 1) % n];
        if (a && b) place(node, (a[0] + b[0]) / 2, (a[1] + b[1]) / 2);
      }
    }
  }

  say(status, error) {
    if (status !== undefined && this.status.textContent !== status) this.status.textContent = status;
    if (error !== undefined && this.error.textContent !== error) this.error.textContent = error;
  }

  render() {
    const admin = this.isAdmin();
    if (!admin && this.active) this.end();
    this.bar.hidden = this.notes.hidden = !admin;
    const on = this.active;
    this.toggle.setAttribute("aria-pressed", String(on));
    this.saveBtn.hidden = this.cancelBtn.hidden = this.removeBtn.hidden = !on;
    this.saveBtn.disabled = this.saving;
    this.removeBtn.disabled = this.selected == null || this.draft.length <= MIN_CORNERS;
    this.removeBtn.textContent = this.selected == null ? "Remove corner" : `Remove corner ${this.selected + 1}`;
    this.map.el.classList.toggle("boundary-editing", on);
    const hint = on && selfCrossing(this.draft) ? "The boundary crosses itself: the server will refuse it." : "";
    if (this.hint.textContent !== hint) this.hint.textContent = hint;
  }

  state() {
    return { active: this.active, draft: this.draft.map((p) => [...p]), selected: this.selected,
      baseVersion: this.base?.version ?? null, saves: this.saves, saving: this.saving,
      status: this.status.textContent, error: this.error.textContent };
  }
}
