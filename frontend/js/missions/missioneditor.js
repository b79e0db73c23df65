// The missions page's editor: the mission type, the area (corners clicked on the pool map, or the whole
// pool) or a formation's leader path, the robots, the sweep width or the formation's spacing, Preview plan,
// and Start / Pause / Resume / Abort of the mission opened. What is being drawn is an overlay of the pool
// map (data-mission-area: its corners). The robots to pick come from the live store (ready or why not).
import { session } from "../core/session.js";
import { store } from "../core/store.js";
import { el } from "../core/util.js";

const ENDED = ["completed", "aborted", "failed"];
const TAP_CLICK_MS = 700; // a tap's own click, after it, is not a second corner

export class MissionEditor {
  /** ``onCreate(body)``: Preview plan; ``onAction(name)``: start, pause, resume, abort; ``besidePlan``: buttons
   * of other parts that go right after Preview plan (Rehearse: rehearsal.js, which enables them itself). */
  constructor(host, map, { onCreate, onAction, besidePlan = [] }) {
    this.map = map;
    this.area = []; // corners clicked on the map ([] = the whole pool)
    this.mission = null;
    this.lastTap = -1e9;
    this.type = el("select", { "aria-label": "Mission type", "data-testid": "mission-type" },
      el("option", { value: "coverage" }, "Coverage sweep"), el("option", { value: "formation" }, "Formation"));
    this.type.addEventListener("change", () => this.setArea([]));
    this.width = el("input", { type: "number", min: "0.05", max: "2", step: "0.05", value: "0.25",
      "aria-label": "Sweep width (m)", "data-testid": "mission-width", style: "width:5em" });
    this.leader = el("select", { "aria-label": "Leader", "data-testid": "mission-leader" });
    this.spacing = el("input", { type: "number", min: "0.3", max: "1.5", step: "0.05", value: "0.5",
      "aria-label": "Formation spacing (m)", "data-testid": "mission-spacing", style: "width:5em" });
    this.loop = el("input", { type: "checkbox", checked: true, "data-testid": "mission-loop" });
    // fixed height: robots arriving later must not move the rest of the page
    this.robotBox = el("div", { class: "mission-robots", "data-testid": "mission-robots", style: "height:4.5em;overflow:auto" });
    this.robotBox.addEventListener("change", () => this.fillLeader());
    const button = (label, testid, fn) =>
      el("button", { type: "button", class: "btn", "data-testid": testid, onclick: () => this.act(fn) }, label);
    this.buttons = {
      pool: button("Whole pool", "mission-pool", async () => this.setArea([])),
      plan: button("Preview plan", "mission-plan", () => onCreate(this.body())),
      start: button("Start", "mission-start", () => onAction("start")),
      pause: button("Pause", "mission-pause", () => onAction("pause")),
      resume: button("Resume", "mission-resume", () => onAction("resume")),
      abort: button("Abort", "mission-abort", () => onAction("abort")),
    };
    this.error = el("div", { class: "error", role: "alert", "data-testid": "mission-error" });
    this.coverageRow = el("div", { class: "row" }, this.buttons.pool, el("label", {}, " width ", this.width, " m"));
    this.formationRow = el("div", { class: "row", hidden: true, "data-testid": "mission-formation-row" },
      el("label", {}, "leader ", this.leader), el("label", {}, " spacing ", this.spacing, " m"),
      el("label", {}, " ", this.loop, " loop"));
    host.append(el("div", { class: "row" }, this.type), this.coverageRow, this.formationRow, this.robotBox,
      el("div", { class: "row mission-actions" }, this.buttons.plan, ...besidePlan,
        ...["start", "pause", "resume", "abort"].map((k) => this.buttons[k])),
      this.error);
    map.overlays.add({ draw: (ctx, proj) => this.draw(ctx, proj) });
    map.onMapClick = (ev, at, kind) => this.click(ev, at, kind);
    map.setClicksTaken(true); // two quick corners are not Plotly's double click (which resets the zoom)
    store.on("robots", () => this.robotsChanged());
    this.robotsChanged();
    this.setArea([]);
  }

  async act(fn) {
    this.error.textContent = "";
    try {
      await fn();
    } catch (err) {
      this.error.textContent = `Refused: ${err.message}`;
    }
  }

  /** A click (or tap) on the map adds a corner, while no mission at work is opened. */
  click(ev, at, kind) {
    if (kind === "dblclick") return true;
    if (kind === "click" && ev.timeStamp - this.lastTap < TAP_CLICK_MS) return true; // the tap's own click
    if (kind === "tap") this.lastTap = ev.timeStamp;
    const m = this.mission;
    if (!session.allows("operator") || (m && !ENDED.includes(m.state) && m.state !== "draft")) return true;
    this.setArea([...this.area, [Math.round(at.x * 100) / 100, Math.round(at.y * 100) / 100]]);
    return true;
  }

  setArea(points) {
    this.area = points;
    this.map.el.dataset.missionArea = String(points.length);
    this.map.dirty = true;
    this.render(this.mission);
  }

  draw(ctx, proj) {
    if (!this.area.length) return;
    ctx.save();
    ctx.beginPath();
    this.area.forEach(([x, y], i) => (i ? ctx.lineTo(proj.px(x), proj.py(y)) : ctx.moveTo(proj.px(x), proj.py(y))));
    if (this.type.value !== "formation") {
      ctx.closePath();
      ctx.fillStyle = "rgba(255, 255, 255, 0.12)";
      ctx.fill();
    }
    ctx.strokeStyle = getComputedStyle(this.map.el).color || "#fff";
    ctx.lineWidth = 2;
    ctx.stroke();
    for (const [x, y] of this.area) ctx.fillRect(proj.px(x) - 3, proj.py(y) - 3, 6, 6);
    ctx.restore();
  }

  /** The robots to pick, from the live store: rebuilt only when one comes, goes or changes readiness. */
  robotsChanged() {
    const robots = [...store.robots.values()].sort((a, b) => a.id.localeCompare(b.id));
    const key = robots.map((r) => `${r.id}:${r.ready}:${(r.not_ready_reasons ?? []).join(",")}`).join("|");
    if (key === this.robotsKey) return;
    this.robotsKey = key;
    const chosen = new Set(this.picked());
    this.robotBox.replaceChildren(...robots.map((r) =>
      el("label", { class: "toggle", title: r.ready ? "ready" : (r.not_ready_reasons || []).join(", ") },
        el("input", { type: "checkbox", value: r.id, checked: chosen.has(r.id), "data-testid": `mission-robot-${r.id}` }),
        ` ${r.id}${r.ready ? "" : ` (not ready: ${(r.not_ready_reasons || []).join(", ") || "unknown"})`} `)));
    this.fillLeader();
  }

  /** The robots picked, in list order. */
  picked() {
    return [...this.robotBox.querySelectorAll("input:checked")].map((i) => i.value);
  }

  /** The leader is one of the robots picked (the first, until another is chosen). */
  fillLeader() {
    const ids = this.picked();
    const keep = ids.includes(this.leader.value) ? this.leader.value : ids[0];
    if (ids.join("\n") !== [...this.leader.options].map((o) => o.value).join("\n")) {
      this.leader.replaceChildren(...ids.map((id) => el("option", { value: id }, id)));
    }
    if (keep) this.leader.value = keep;
  }

  /** The body of POST /api/missions from what is drawn and picked (the drawing is cleared once it is made). */
  body() {
    const robots = this.picked();
    if (this.type.value !== "formation") {
      const area = this.area.length >= 3 ? { area: this.area } : {};
      return { type: "coverage", name: "", robots, params: { sweep_width_m: Number(this.width.value), ...area } };
    }
    if (this.area.length < 2) throw new Error("click at least two points of the leader's path on the map");
    const leader = this.leader.value || robots[0];
    const d = Number(this.spacing.value);
    const slots = Object.fromEntries(robots.filter((r) => r !== leader).map((r, i) => {
      const rank = Math.floor(i / 2) + 1;
      return [r, [-d * rank, (i % 2 ? -1 : 1) * d * rank]];
    }));
    return { type: "formation", name: "", robots, params: { leader, path: this.area, slots, loop: this.loop.checked } };
  }

  hint() {
    if (!session.allows("operator")) return "Read-only.";
    return this.type.value === "formation"
      ? "Click the leader's path on the map (two points or more), pick the robots and the leader, preview."
      : "Draw an area on the map (click its corners) or take the whole pool, pick robots, preview.";
  }

  render(m) {
    this.mission = m;
    const can = session.allows("operator");
    const state = m?.state;
    const idle = !m || ENDED.includes(state);
    this.buttons.plan.disabled = !can || !(idle || state === "draft");
    this.buttons.start.disabled = !can || state !== "draft";
    this.buttons.pause.disabled = !can || state !== "running";
    this.buttons.resume.disabled = !can || state !== "paused";
    this.buttons.abort.disabled = !can || !["draft", "running", "paused"].includes(state);
    this.buttons.pool.disabled = !can;
    const formation = this.type.value === "formation";
    this.coverageRow.hidden = formation;
    this.formationRow.hidden = !formation;
    this.map.el.dataset.drawing = formation ? "leader-path" : "area";
  }
}
