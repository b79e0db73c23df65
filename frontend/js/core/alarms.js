// Alarms: a banner on every page with the count of unacknowledged alarms, a list with Acknowledge buttons,
// and an optional sound for critical ones (off by default, remembered in the browser).
import { api } from "./api.js";
import { session } from "./session.js";
import { store } from "./store.js";
import { el } from "./util.js";

const SOUND_KEY = "fleet-alarm-sound";
const open = new Map(); // id -> alarm (active or acknowledged)
// A load asks for the open alarms while the WebSocket may bring newer ones: the reply of the latest load
// replaces the list, then the alarms heard since that load was sent are applied again over it. An older
// load's reply is dropped. Without this, a reply sent before an alarm was raised but read after it wiped
// the alarm from the banner until the next one (a page opened just as a battery went critical).
let loads = 0;
let heardDuringLoad = null; // id -> the latest alarm heard while the latest load is on its way

function beep() {
  try {
    const ctx = new AudioContext();
    const osc = ctx.createOscillator();
    osc.frequency.value = 880;
    osc.connect(ctx.destination);
    osc.start();
    osc.stop(ctx.currentTime + 0.25);
  } catch {
    /* no audio device: the banner says it all */
  }
}

function apply(alarm) {
  heardDuringLoad?.set(alarm.id, alarm);
  const before = open.get(alarm.id);
  if (alarm.state === "cleared") open.delete(alarm.id);
  else open.set(alarm.id, alarm);
  if (!before && alarm.state === "active" && alarm.severity === "critical" && localStorage.getItem(SOUND_KEY) === "on") beep();
  render();
}

function render() {
  const banner = document.getElementById("alarm-banner");
  if (!banner) return;
  const active = [...open.values()].filter((a) => a.state === "active");
  banner.hidden = open.size === 0;
  const critical = active.some((a) => a.severity === "critical");
  banner.classList.toggle("critical", critical);
  const summary = banner.querySelector("[data-testid=alarm-count]");
  summary.textContent = active.length
    ? `${active.length} alarm${active.length > 1 ? "s" : ""} need${active.length > 1 ? "" : "s"} attention`
    : `${open.size} acknowledged alarm${open.size > 1 ? "s" : ""} still open`;
  const list = banner.querySelector("[data-testid=alarm-list]");
  const rows = [...open.values()].sort((a, b) => b.raised_at - a.raised_at).map((a) => {
    const ack = el("button", { type: "button", "data-testid": `alarm-ack-${a.id}` }, "Acknowledge");
    ack.disabled = a.state !== "active" || !session.allows("operator");
    ack.addEventListener("click", async () => {
      ack.disabled = true;
      try {
        apply(await api.post(`/api/alarms/${a.id}/ack`));
      } catch (err) {
        ack.replaceWith(el("span", { class: "why" }, err.message));
      }
    });
    return el("li", { dataset: { alarm: a.kind, state: a.state, severity: a.severity, robot: a.robot_id ?? "" } },
      el("span", { class: `badge ${a.severity === "critical" ? "stopped" : "stale"}` }, a.severity),
      ` ${a.robot_id ?? "fleet"} · ${a.kind.replaceAll("_", " ")}: ${a.message} `,
      a.state === "acknowledged" ? el("span", { class: "muted" }, `acknowledged by ${a.acked_by} `) : ack);
  });
  list.replaceChildren(...rows);
}

export function setupAlarms() {
  const banner = document.getElementById("alarm-banner");
  if (!banner) return;
  const toggle = banner.querySelector("[data-testid=alarm-toggle]");
  const list = banner.querySelector("[data-testid=alarm-list]");
  toggle.addEventListener("click", () => {
    list.hidden = !list.hidden;
    toggle.setAttribute("aria-expanded", String(!list.hidden));
  });
  const sound = banner.querySelector("[data-testid=alarm-sound]");
  sound.checked = localStorage.getItem(SOUND_KEY) === "on";
  sound.addEventListener("change", () => localStorage.setItem(SOUND_KEY, sound.checked ? "on" : "off"));
  store.on("alarm", apply);
  store.on("connection", (up) => up && load());
  load();
}

async function load() {
  const mine = ++loads;
  const heard = (heardDuringLoad = new Map());
  try {
    const alarms = await api.get("/api/alarms?state=open");
    if (mine !== loads) return; // a newer load is on its way, and its reply is newer than this one
    open.clear();
    for (const a of alarms) open.set(a.id, a);
    for (const [id, a] of heard) {
      if (a.state === "cleared") open.delete(id);
      else open.set(id, a);
    }
    render();
  } catch {
    /* not logged in yet, or offline: the live connection brings them */
  } finally {
    if (heardDuringLoad === heard) heardDuringLoad = null;
  }
}
