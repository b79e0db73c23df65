// The fleet E-STOP: always in reach (the top bar; on phones a full-width dock at the bottom edge), Esc
// anywhere (any logged-in user, viewers too). While engaged, a bar over the page (it never moves the
// layout) says who pressed it, holds Release (away from the E-STOP) and lists every robot with its ack
// (GET /api/estop). Releasing needs an operator and a second, confirming press within CONFIRM_MS; viewers
// see why they cannot, inline.
import { announce } from "../core/a11y.js";
import { api } from "../core/api.js";
import { session } from "../core/session.js";
import { store } from "../core/store.js";
import { el } from "../core/util.js";

const POLL_MS = 300;
const CONFIRM_MS = 4000;
const RELEASE_LABEL = "Release e-stop";
const CONFIRM_LABEL = "Tap again to release";

export function setupEstop() {
  const button = document.getElementById("estop");
  const release = document.getElementById("estop-release");
  const status = document.getElementById("estop-status");
  const bar = document.getElementById("estop-bar");
  const reasonEl = document.getElementById("estop-reason");
  const noteEl = document.getElementById("estop-release-note");
  const acksEl = document.getElementById("estop-acks");
  let polling = null;
  let confirmTimer = null;
  let wasEngaged = null;

  async function engage() {
    try {
      await api.estop("dashboard");
    } catch (err) {
      status.hidden = false;
      status.textContent = `E-STOP request failed: ${err.message}`;
      announce(`E-stop request failed: ${err.message}`, true);
    }
  }

  function stopPolling() {
    clearInterval(polling);
    polling = null;
  }

  function disarmRelease() {
    clearTimeout(confirmTimer);
    confirmTimer = null;
    release.classList.remove("confirm");
    release.textContent = RELEASE_LABEL;
  }

  async function showAcks() {
    try {
      const state = await api.estopState();
      // a reply to a poll sent while engaged can arrive after the WebSocket has said "released": it is an
      // older state (its press's time), and taking it would show the e-stop engaged again and block driving
      if ((state.ts ?? 0) < (store.estop?.ts ?? 0)) return;
      render(state);
      const online = [...store.robots.values()].filter((r) => r.online).map((r) => r.id);
      if (!state.engaged || online.every((id) => id in (state.acks ?? {}))) stopPolling();
    } catch {
      /* the WS message already shows the state */
    }
  }

  function announceChange(engaged) {
    if (wasEngaged === null) {
      wasEngaged = engaged;
      if (!engaged) return; // a page opened with the fleet running says nothing
    } else if (wasEngaged === engaged) {
      return;
    }
    wasEngaged = engaged;
    const who = store.estop.source ? ` by ${store.estop.source}` : "";
    announce(engaged ? `E-stop engaged${who}. Every robot stops.` : `E-stop released${who}. Robots may drive again.`, true);
  }

  function render(state) {
    store.estop = { ...store.estop, ...state };
    const engaged = Boolean(store.estop.engaged);
    status.hidden = !engaged;
    release.hidden = !engaged;
    bar.hidden = !engaged;
    button.classList.toggle("latched", engaged);
    button.setAttribute("aria-pressed", String(engaged));
    button.textContent = engaged ? "E-STOPPED" : "E-STOP";
    const mayRelease = session.allows("operator");
    release.disabled = !mayRelease;
    release.title = mayRelease ? "Let the robots take drive commands again" : "Releasing needs the operator role";
    noteEl.hidden = !engaged || mayRelease;
    noteEl.textContent = mayRelease ? "" : `Releasing needs the operator role (you are ${session.me?.role ?? "?"}).`;
    document.body.classList.toggle("estopped", engaged);
    announceChange(engaged);
    if (!engaged) {
      disarmRelease();
      return;
    }
    const acks = store.estop.acks ?? {};
    const robots = [...store.robots.values()].sort((a, b) => a.id.localeCompare(b.id));
    const online = robots.filter((r) => r.online);
    const acked = online.filter((r) => r.id in acks).length;
    status.textContent = `ENGAGED · ${acked}/${online.length} acked`;
    const by = store.estop.source ? `pressed by ${store.estop.source}` : "";
    reasonEl.textContent = [by, store.estop.reason].filter(Boolean).join(" · ");
    acksEl.replaceChildren(...robots.map((r) => {
      const ack = acks[r.id];
      const cls = ack ? "acked" : r.online ? "waiting" : "offline";
      const text = ack ?? (r.online ? "waiting…" : "offline");
      return el("li", { class: cls, dataset: { robot: r.id, ack: ack ?? "" } }, el("strong", {}, r.id), ` ${text}`);
    }));
  }

  button.addEventListener("click", engage);
  // two presses: the first arms (the button says so for CONFIRM_MS), the second releases
  release.addEventListener("click", async () => {
    if (!release.classList.contains("confirm")) {
      release.classList.add("confirm");
      release.textContent = CONFIRM_LABEL;
      announce("Press release again to confirm.");
      confirmTimer = setTimeout(disarmRelease, CONFIRM_MS);
      return;
    }
    disarmRelease();
    try {
      await api.release();
    } catch (err) {
      noteEl.hidden = false;
      noteEl.textContent = `Release failed: ${err.message}`;
    }
  });
  window.addEventListener("keydown", (ev) => {
    if (ev.key === "Escape") {
      ev.preventDefault();
      engage();
    }
  });
  store.on("estop", (state) => {
    render(state);
    if (state.engaged && !polling) {
      showAcks();
      polling = setInterval(showAcks, POLL_MS);
    } else if (!state.engaged) {
      stopPolling();
    }
  });
  store.on("robots", () => {
    if (!store.estop?.engaged) return;
    render(store.estop);
    if (!polling) showAcks();
  });
  store.on("session", () => render(store.estop));
}
