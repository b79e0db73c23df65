// Events timeline: robots online/offline, e-stop and release, sensor failures, refused input, markers. Live,
// the list is polled (GET /api/events); a replay gives its own source (the run's events up to the replay
// time, replaycursor.js): {events(limit) -> newest first, on("events", fn)}.
import { api } from "../core/api.js";
import { Emitter } from "../core/store.js";
import { clock, el } from "../core/util.js";

const POLL_MS = 3000;
const SHOW = 40;
const LABELS = {
  online: "online", offline: "offline", estop: "E-STOP", estop_release: "e-stop released",
  reject: "refused input", estop_ack: "e-stop ack", sensor_failed: "sensor failed", sensor_recovered: "sensor recovered",
  marker: "marker", run_start: "run started", run_stop: "run stopped", run_frames_stopped: "run frames stopped",
};
const CLASS = { offline: "st-rejected", estop: "st-rejected", sensor_failed: "st-expired", reject: "st-expired",
  online: "st-done", estop_ack: "st-done", sensor_recovered: "st-done", estop_release: "st-accepted" };

function describe(ev) {
  const d = ev.detail ?? {};
  if (ev.kind.startsWith("sensor_")) return `${d.sensor ?? ""}${d.error ? `: ${d.error}` : ""}`;
  if (ev.kind === "estop_ack") return [d.status, d.reason].filter(Boolean).join(" · ");
  if (ev.kind === "reject") return [d.kind, d.reason, d.topic].filter(Boolean).join(" · ");
  if (ev.kind === "estop" || ev.kind === "estop_release") return [d.reason, d.source].filter(Boolean).join(" · ");
  if (ev.kind === "marker") return d.text ?? "";
  if (ev.kind.startsWith("run_")) return [d.name ? `“${d.name}”` : `run ${d.run_id}`, d.reason].filter(Boolean).join(" · ");
  return d.source ? `via ${d.source}` : "";
}

/** The live events: the newest, polled while the page is visible. */
export class LiveEvents extends Emitter {
  constructor() {
    super();
    this.latest = null; // null: not polled yet (nothing shown, not "no events")
    this.poll();
    setInterval(() => this.poll(), POLL_MS);
  }

  async poll() {
    if (document.hidden) return;
    try {
      this.latest = await api.get(`/api/events?limit=${SHOW}`);
    } catch {
      return;
    }
    this.emit("events");
  }

  events() {
    return this.latest;
  }
}

export class EventsPanel {
  constructor(host, { source = new LiveEvents(), testid = "events" } = {}) {
    this.source = source;
    this.list = el("ul", { class: "log", "data-testid": testid });
    host.replaceChildren(el("h3", {}, "Events"), this.list);
    source.on("events", () => this.render());
    this.render();
  }

  render() {
    const events = this.source.events(SHOW);
    if (!events) return;
    this.list.replaceChildren(...events.map((ev) =>
      el("li", { dataset: { kind: ev.kind, robot: ev.robot_id ?? "" } },
        el("span", { class: "when" }, clock(ev.ts)),
        el("span", {}, el("span", { class: CLASS[ev.kind] ?? "" }, LABELS[ev.kind] ?? ev.kind),
          ev.robot_id ? el("strong", {}, ` ${ev.robot_id}`) : null),
        el("span", { class: "steps" }, describe(ev)))));
    if (!events.length) this.list.append(el("li", { class: "muted empty" }, "No events yet."));
  }
}
