// Go-to and path mode on the fleet map. A click on the map moves a robot only when Go-to is armed for the
// selected robot: the "Go to" or "Path" toggle, or Shift held while clicking (a momentary arm). Go to: a
// click sends `goto` there. Path: clicks add waypoints (drawn as a polyline from the robot); a double
// click or "Send path" sends `follow_path`. While a goal runs (the robot's `motion` stream, 5 Hz or more)
// the map shows the goal, the path that remains and the distance, with Cancel (a `stop`). How a goal
// ended (done, or failed: geofence, timeout, no_position ...) is said inline under the map.
// Changing the robot or an e-stop disarms the mode, so an old arm never applies to another robot.
import { api } from "../core/api.js";
import { controlReason } from "./control.js";
import { store } from "../core/store.js";
import { themeColors } from "../core/theme.js";
import { el } from "../core/util.js";

const TOLERANCE_M = 0.05;
const MAX_WAYPOINTS = 500;
/** A waypoint this close to the previous one is the same click (a double click adds two). */
const SAME_POINT_M = 0.02;
/** The motion stream comes at 5 Hz or more: older than this, the goal is no longer known to run. */
const LIVE_S = 1.0;
const TAP_CLICK_MS = 500;
const DOUBLE_CLICK_MS = 400;
const DOUBLE_CLICK_PX = 8;
/** How long a geofence event (a drive stopped or refused at the fence) stays on screen. */
const FENCE_NOTE_S = 10;
const FINAL = new Set(["rejected", "done", "expired", "failed", "aborted", "timeout"]);

export class GoToPanel {
  constructor(host, fleetMap) {
    this.map = fleetMap;
    this.mode = "off"; // "off" | "goto" | "path"
    this.armedFor = null;
    this.draft = []; // path waypoints [[x, y]]
    this.goal = null; // the last goal sent from here: {id, robot, mode, x, y, points, status}
    this.result = null; // how it ended: {status, reason, robot}
    this.error = ""; // a refusal before anything was sent (no robot, e-stop, 409 ...)
    this.sent = 0;
    this.lastTap = 0;
    this.lastClick = null; // {t, x, y} of the last click on the map (double clicks)
    this.pathSentAt = -1e9;
    this.gotoBtn = el("button", { type: "button", class: "btn", "data-testid": "goto-toggle", "aria-pressed": "false",
      title: "Arm Go-to: a click on the map sends the selected robot there (or hold Shift while clicking)" }, "Go to");
    this.pathBtn = el("button", { type: "button", class: "btn", "data-testid": "path-toggle", "aria-pressed": "false",
      title: "Path mode: clicks add waypoints; double-click or Send path sends them" }, "Path");
    this.sendBtn = el("button", { type: "button", class: "btn primary", "data-testid": "path-send" }, "Send path");
    this.clearBtn = el("button", { type: "button", class: "btn", "data-testid": "path-clear" }, "Clear");
    this.cancelBtn = el("button", { type: "button", class: "btn cancel", "data-testid": "goto-cancel" }, "Cancel goal");
    this.statusEl = el("div", { class: "goto-status", "data-testid": "goto-status" });
    // how the last goal ended, then (when there is one) the robot's last geofence event
    this.resultEl = el("span", { "data-testid": "goto-result" });
    this.fenceEl = el("span", { class: "bad", "data-testid": "fence-note" });
    this.notes = el("div", { class: "goto-notes", role: "status" }, this.resultEl, this.fenceEl);
    this.fence = null; // the selected robot's last geofence event {robot, event, reason, at}
    host.replaceChildren(el("div", { class: "goto-bar", role: "group", "aria-label": "Go to and path" },
      this.gotoBtn, this.pathBtn, this.sendBtn, this.clearBtn, this.cancelBtn), this.statusEl, this.notes);
    this.gotoBtn.addEventListener("click", () => this.arm(this.mode === "goto" ? "off" : "goto"));
    this.pathBtn.addEventListener("click", () => this.arm(this.mode === "path" ? "off" : "path"));
    this.sendBtn.addEventListener("click", () => this.sendPath());
    this.clearBtn.addEventListener("click", () => {
      this.draft = [];
      this.render();
    });
    this.cancelBtn.addEventListener("click", () => this.cancel());
    fleetMap.onMapClick = (ev, at, kind) => this.onMapClick(ev, at, kind);
    this.id = "goals"; // a layer of the map (map/layers.js), over the robots
    this.label = "goals and paths";
    fleetMap.addLayer(this, { over: true });
    store.on("command", (cmd) => this.onCommand(cmd));
    store.on("telemetry", (msg) => {
      if (msg.stream !== "geofence" || !["stopped", "refused", "outside"].includes(msg.data?.event)) return;
      this.fence = { robot: msg.robot_id, event: msg.data.event, reason: msg.data.reason ?? "", at: Date.now() / 1000 };
      this.render();
    });
    store.on("estop", (e) => e?.engaged && this.arm("off"));
    setInterval(() => this.render(), 250); // the distance, the selection and the live goal's age
    this.render();
  }

  get robot() {
    return this.map.selected;
  }

  arm(mode) {
    if (mode !== "off" && this.map.editing) { // the boundary editor holds the map's clicks
      this.error = "Finish editing the boundary first (Save or Cancel).";
      this.render();
      return;
    }
    this.mode = mode;
    this.armedFor = mode === "off" ? null : this.robot;
    if (mode !== "path") this.draft = [];
    this.error = mode !== "off" && !this.robot ? "Select a robot first (click it on the map or in the list)." : "";
    this.render();
  }

  onMapClick(ev, at, kind) {
    if (this.mode !== "off" && this.armedFor !== this.robot) this.arm("off"); // another robot was selected
    const armed = this.mode !== "off" || (ev.shiftKey && kind !== "tap");
    if (!armed || !this.robot) return false; // a plain click selects robots, nothing more
    if (kind === "click" && ev.timeStamp - this.lastTap < TAP_CLICK_MS) return true; // the tap's own click
    if (kind === "tap") this.lastTap = ev.timeStamp;
    // Plotly's drag layer turns presses into its own clicks and keeps the double click (to reset the zoom):
    // a second click close in time and place is the double click here
    const prev = this.lastClick;
    this.lastClick = kind === "dblclick" ? null : { t: ev.timeStamp, x: ev.clientX, y: ev.clientY };
    if (kind === "dblclick") {
      if (this.mode === "path" && ev.timeStamp - this.pathSentAt > DOUBLE_CLICK_MS) this.sendPath();
      return true;
    }
    if (prev && ev.timeStamp - prev.t < DOUBLE_CLICK_MS && Math.hypot(ev.clientX - prev.x, ev.clientY - prev.y) < DOUBLE_CLICK_PX) {
      this.lastClick = null;
      if (this.mode === "path") {
        this.pathSentAt = ev.timeStamp;
        this.sendPath();
      }
      return true; // in Go-to mode the first click sent the goal already
    }
    const p = [round(at.x), round(at.y)];
    if (this.mode === "path") {
      const last = this.draft[this.draft.length - 1];
      if (!last || Math.hypot(p[0] - last[0], p[1] - last[1]) > SAME_POINT_M) {
        if (this.draft.length < MAX_WAYPOINTS) this.draft.push(p);
        else this.error = `A path has at most ${MAX_WAYPOINTS} waypoints.`;
      }
      this.map.dirty = true;
      this.render();
      return true;
    }
    this.send("goto", { x: p[0], y: p[1], tolerance_m: TOLERANCE_M }, { x: p[0], y: p[1] });
    return true;
  }

  sendPath() {
    if (!this.draft.length) {
      this.error = "Click the map to add waypoints first.";
      this.render();
      return;
    }
    const points = this.draft.map((p) => [...p]);
    const last = points[points.length - 1];
    this.send("follow_path", { waypoints: points, tolerance_m: TOLERANCE_M }, { x: last[0], y: last[1], points });
    this.draft = [];
  }

  send(command, args, shape) {
    const robot = this.robot;
    const why = controlReason(robot, command);
    if (why) {
      this.error = why;
      this.render();
      return;
    }
    this.sent += 1;
    this.error = "";
    api.command(robot, command, args, { ttl_s: 2.0, source: "ui-goto" }).then(
      (cmd) => {
        this.goal = { id: cmd.id, robot, mode: command, status: cmd.status, ...shape };
        this.result = null;
        const known = store.commands.get(cmd.id); // the live connection may have brought its acks first
        if (known) this.onCommand(known);
        this.render();
      },
      (err) => {
        this.error = `${command} refused: ${err.message}`;
        this.render();
      },
    );
    this.render();
  }

  cancel() {
    const robot = this.activeGoal()?.robot ?? this.robot;
    if (!robot) return;
    api.command(robot, "stop", {}, { ttl_s: 1.0, source: "ui-goto" }).catch((err) => {
      this.error = `stop refused: ${err.message}`;
      this.render();
    });
  }

  onCommand(cmd) {
    if (!this.goal || cmd.id !== this.goal.id) return;
    this.goal.status = cmd.status;
    if (FINAL.has(cmd.status)) {
      this.result = { status: cmd.status, reason: cmd.reason ?? "", robot: this.goal.robot, mode: this.goal.mode };
      this.goal = null;
      this.map.dirty = true;
    }
    this.render();
  }

  /** The selected robot's running goal: its motion report (anyone's goal, from here, REST or a script)
   * merged with what this page sent (the waypoints themselves), or null. */
  activeGoal() {
    const robot = this.robot;
    if (!robot) return null;
    const m = store.latest.get(robot)?.motion;
    const live = m && Date.now() / 1000 - m.received < LIVE_S && m.data?.state === "active"
      && (m.data.mode === "goto" || m.data.mode === "follow_path") ? m.data : null;
    const mine = this.goal?.robot === robot ? this.goal : null;
    if (!live && !mine) return null;
    if (live && mine && live.command_id !== mine.id) return fromMotion(robot, live); // another goal took over
    if (!live) return { ...mine, distance: null, waypoint: null };
    const g = fromMotion(robot, live);
    return mine ? { ...g, points: mine.points ?? null } : g;
  }

  render() {
    const robot = this.robot;
    if (this.mode !== "off" && this.armedFor !== robot) {
      this.mode = "off";
      this.armedFor = null;
      this.draft = [];
    }
    const goal = this.activeGoal();
    this.gotoBtn.setAttribute("aria-pressed", String(this.mode === "goto"));
    this.gotoBtn.disabled = this.pathBtn.disabled = Boolean(this.map.editing);
    this.pathBtn.setAttribute("aria-pressed", String(this.mode === "path"));
    this.sendBtn.hidden = this.mode !== "path";
    this.clearBtn.hidden = this.mode !== "path";
    this.sendBtn.disabled = this.draft.length === 0;
    this.cancelBtn.hidden = !goal;
    this.map.el.classList.toggle("goto-armed", this.mode !== "off");
    if (this.clicksTaken !== (this.mode !== "off")) {
      this.clicksTaken = this.mode !== "off";
      this.map.setClicksTaken(this.clicksTaken);
    }
    let status;
    if (goal) {
      const dist = goal.distance == null ? "" : ` · ${goal.distance.toFixed(2)} m to go`;
      const wp = goal.mode === "follow_path" && goal.waypoint != null
        ? ` · waypoint ${goal.waypoint + 1}${goal.count ? `/${goal.count}` : ""}` : "";
      const where = goal.x == null ? "" : ` (${goal.x.toFixed(2)}, ${goal.y.toFixed(2)})`;
      status = `${goal.robot}: ${goal.mode === "goto" ? "going to" : "following a path to"}${where}${wp}${dist}`;
    } else if (this.mode === "goto") {
      status = `Go-to armed: click the map to send ${robot} there.`;
    } else if (this.mode === "path") {
      status = `Path for ${robot}: ${this.draft.length} waypoint${this.draft.length === 1 ? "" : "s"}; double-click or Send path.`;
    } else {
      status = ""; // idle: the buttons' names and titles say what they do (phones keep the room for the pad)
    }
    set(this.statusEl, status);
    this.statusEl.classList.toggle("idle", status === ""); // (phones fold an idle status away)
    const r = this.result;
    let text = this.error;
    let kind = this.error ? "bad" : "";
    if (!text && r) {
      text = r.status === "done" ? `${r.robot}: goal reached.` : `${r.robot}: ${r.mode} ${r.status}${r.reason ? `: ${r.reason}` : ""}`;
      kind = r.status === "done" ? "ok" : r.status === "aborted" ? "" : "bad";
    }
    set(this.resultEl, text);
    const f = this.fence && this.fence.robot === robot && Date.now() / 1000 - this.fence.at < FENCE_NOTE_S ? this.fence : null;
    const what = { stopped: "stopped at the fence", refused: "refused at the fence", outside: "drifted outside the fence" };
    set(this.fenceEl, f ? `${f.robot}: geofence, ${what[f.event]}${f.reason ? `: ${f.reason}` : ""}` : "");
    this.resultEl.className = kind;
    this.resultEl.dataset.status = r?.status ?? "";
  }

  /** The live layer: the path being drawn, the goal, the remaining path and the distance. */
  draw(ctx, proj) {
    const c = themeColors();
    const pos = this.robot ? store.robots.get(this.robot)?.position : null;
    const at = pos && Number.isFinite(pos.x) ? [pos.x, pos.y] : null;
    const line = (pts, dash) => {
      if (pts.length < 2) return;
      ctx.setLineDash(dash);
      ctx.beginPath();
      ctx.moveTo(proj.px(pts[0][0]), proj.py(pts[0][1]));
      for (const p of pts.slice(1)) ctx.lineTo(proj.px(p[0]), proj.py(p[1]));
      ctx.stroke();
      ctx.setLineDash([]);
    };
    ctx.save();
    ctx.strokeStyle = c.accent;
    ctx.fillStyle = c.accent;
    ctx.lineWidth = 2;
    if (this.mode === "path" && this.draft.length) {
      line(at ? [at, ...this.draft] : this.draft, [6, 4]);
      for (const [x, y] of this.draft) ctx.fillRect(proj.px(x) - 3, proj.py(y) - 3, 6, 6);
    }
    ctx.restore();
    drawGoal(ctx, proj, this.activeGoal(), at, c.accent, c.fg);
  }

  state() {
    return { mode: this.mode, armedFor: this.armedFor, draft: this.draft.map((p) => [...p]), goal: this.goal,
      active: this.activeGoal(), result: this.result, error: this.error, sent: this.sent };
  }
}

/** A goal on the map (the live Go-to panel's, or a robot's in a replay): the path that remains from the robot
 * at ``at`` ([x, y] or null), a ring of the goal's tolerance with a cross, and the distance left. */
export function drawGoal(ctx, proj, goal, at, color, textColor) {
  if (!goal || goal.x == null) return;
  ctx.save();
  ctx.strokeStyle = color;
  ctx.fillStyle = color;
  ctx.lineWidth = 2;
  const rest = goal.points ? goal.points.slice(Math.max(0, goal.waypoint ?? 0)) : [[goal.x, goal.y]];
  const pts = at ? [at, ...rest] : rest;
  if (pts.length >= 2) {
    ctx.setLineDash([4, 3]);
    ctx.beginPath();
    ctx.moveTo(proj.px(pts[0][0]), proj.py(pts[0][1]));
    for (const p of pts.slice(1)) ctx.lineTo(proj.px(p[0]), proj.py(p[1]));
    ctx.stroke();
    ctx.setLineDash([]);
  }
  const gx = proj.px(goal.x), gy = proj.py(goal.y);
  const r = Math.max(6, Math.abs(proj.px(goal.x + (goal.tolerance ?? TOLERANCE_M)) - gx));
  ctx.beginPath();
  ctx.arc(gx, gy, r, 0, 2 * Math.PI);
  ctx.stroke();
  ctx.beginPath();
  ctx.moveTo(gx - r - 4, gy);
  ctx.lineTo(gx + r + 4, gy);
  ctx.moveTo(gx, gy - r - 4);
  ctx.lineTo(gx, gy + r + 4);
  ctx.stroke();
  if (goal.distance != null) {
    ctx.font = "11px system-ui, sans-serif";
    ctx.textAlign = "left";
    ctx.textBaseline = "bottom";
    ctx.fillStyle = textColor;
    ctx.fillText(`${goal.distance.toFixed(2)} m`, gx + r + 4, gy - 4);
  }
  ctx.restore();
}

/** A goal as the motion stream reports it. */
export function fromMotion(robot, d) {
  const g = d.goal ?? {};
  const [x, y] = Number.isFinite(g.x) ? [g.x, g.y] : Array.isArray(g.last) ? g.last : [null, null];
  return { id: d.command_id, robot, mode: d.mode, x, y, tolerance: g.tolerance_m, points: null,
    distance: Number.isFinite(d.distance_m) ? d.distance_m : null, waypoint: d.waypoint_index ?? null,
    count: d.waypoint_count ?? null };
}

function round(v) {
  return Math.round(v * 1000) / 1000;
}

function set(node, text) {
  if (node.textContent !== text) node.textContent = text;
}
