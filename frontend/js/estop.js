// The fleet E-STOP: always in the top bar, Esc anywhere (any logged-in user, viewers too). While engaged,
// a bar under the top bar lists every robot with its ack (GET /api/estop); releasing needs an operator.
import { api } from "./api.js";
import { session } from "./session.js";
import { store } from "./store.js";
import { el } from "./util.js";

const POLL_MS = 300;

export function setupEstop() {
  const button = document.getElementById("estop");
  const release = document.getElementById("estop-release");
  const status = document.getElementById("estop-status");
  const bar = document.getElementById("estop-bar");
  const reasonEl = document.getElementById("estop-reason");
  const acksEl = document.getElementById("estop-acks");
  let polling = null;

  async function engage() {
    try {
      await api.estop("dashboard");
    } catch (err) {
      status.hidden = false;
      status.textContent = `E-STOP request failed: ${err.message}`;
    }
  }

  function stopPolling() {
    clearInterval(polling);
    polling = null;
  }

  async function showAcks() {
    try {
      const state = await api.estopState();
      render(state);
      const online = [...store.robots.values()].filter((r) => r.online).map((r) => r.id);
      if (!state.engaged || online.every((id) => id in (state.acks ?? {}))) stopPolling();
    } catch {
      /* the WS message already shows the state */
    }
  }

  function render(state) {
    store.estop = { ...store.estop, ...state };
    const engaged = Boolean(store.estop.engaged);
    status.hidden = !engaged;
    release.hidden = !engaged;
    bar.hidden = !engaged;
    const mayRelease = session.allows("operator");
    release.disabled = !mayRelease;
    release.title = mayRelease ? "Let the robots take drive commands again" : "Releasing needs the operator role";
    document.body.classList.toggle("estopped", engaged);
    if (!engaged) return;
    const acks = store.estop.acks ?? {};
    const robots = [...store.robots.values()].sort((a, b) => a.id.localeCompare(b.id));
    const online = robots.filter((r) => r.online);
    const acked = online.filter((r) => r.id in acks).length;
    status.textContent = `E-STOP ENGAGED · ${acked}/${online.length} robots acked`;
    reasonEl.textContent = [store.estop.reason, store.estop.source].filter(Boolean).join(" · ");
    acksEl.replaceChildren(...robots.map((r) => {
      const ack = acks[r.id];
      const cls = ack ? "acked" : r.online ? "waiting" : "offline";
      const text = ack ?? (r.online ? "waiting…" : "offline");
      return el("li", { class: cls, dataset: { robot: r.id, ack: ack ?? "" } }, el("strong", {}, r.id), ` ${text}`);
    }));
  }

  button.addEventListener("click", engage);
  release.addEventListener("click", async () => {
    try {
      await api.release();
    } catch (err) {
      status.textContent = `release failed: ${err.message}`;
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
