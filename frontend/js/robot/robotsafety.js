// The robot page's safety panel: "hold this robot" (a per-robot stop latch beside the fleet e-stop) and,
// for robots on the old Mollusca framework, what the server can and cannot guarantee for them.
import { api } from "../core/api.js";
import { session } from "../core/session.js";
import { store } from "../core/store.js";
import { el } from "../core/util.js";

const LEGACY_WARNING =
  "Old framework: this robot has no deadman or e-stop of its own. The server stops it (e-stop, lapsed " +
  "drives, its own crash or shutdown), but it drives until it hears \"stop\": if the robot loses the " +
  "broker mid-drive, nothing can reach it. See docs/migrating-from-the-mollusca-framework.md.";

export function renderSafety(host, r, onError) {
  if (!host) return;
  if (!r) {
    host.replaceChildren();
    delete host.dataset.key;
    return;
  }
  const lease = r.lease && Date.now() / 1000 - r.lease.last_drive <= r.lease.lapse_s ? r.lease : null;
  const key = JSON.stringify([r.id, r.online, r.legacy, r.legacy_listens_on, r.legacy_unit, r.hold, session.me?.role,
    lease?.holder, lease?.holder_name]);
  const agoEl = host.querySelector("[data-role=lease-ago]");
  if (agoEl && lease) agoEl.textContent = `${Math.max(0, Math.round(Date.now() / 1000 - lease.last_drive))} s ago`;
  if (host.dataset.key === key) return; // re-rendered only on change: a click must not lose its button
  host.dataset.key = key;
  const parts = [];
  if (r.legacy) {
    const unit = r.legacy_unit ?? [];
    const shared = r.legacy_listens_on !== "own";
    parts.push(el("div", { class: "legacy-warning", role: "note", "data-testid": "legacy-warning" },
      el("strong", {}, "Legacy robot. "), LEGACY_WARNING));
    parts.push(el("div", { class: "legacy-unit", "data-testid": "legacy-unit" }, shared
      ? `Listens on the shared topic: a drive here drives every old-framework robot (${unit.join(", ") || r.id}).`
      : `Listens on its own topic (${r.id}/control/commands): drives move this robot only.`));
  }
  const hold = r.hold;
  const button = el("button", {
    type: "button", class: hold ? "release-hold" : "hold", "data-testid": hold ? "hold-release" : "hold-robot",
  }, hold ? "Release hold" : "Hold this robot");
  const canRelease = session.allows("operator");
  if (hold && !canRelease) button.disabled = true;
  button.addEventListener("click", async () => {
    button.disabled = true;
    try {
      if (hold) await api.releaseHold(r.id);
      else await api.hold(r.id, "held from the dashboard");
    } catch (err) {
      onError?.(err.message);
    } finally {
      button.disabled = false;
    }
  });
  const state = hold
    ? el("span", { class: "badge stopped", "data-testid": "hold-state" }, `held by ${hold.source}${hold.reason ? ` · ${hold.reason}` : ""}`)
    : el("span", { class: "muted" }, "Stops it and refuses its drives until released.");
  parts.push(el("div", { class: "hold-row" }, button, " ", state,
    hold && !canRelease ? el("div", { class: "reason" }, "Releasing a hold needs the operator role.") : null));
  parts.push(controlRow(r, lease, onError));
  if (session.allows("admin") && !r.online) parts.push(forgetRow(r));
  host.replaceChildren(el("section", { class: "safety", "aria-label": "robot safety" }, el("h3", {}, "Safety"), ...parts));
}

function action(label, testid, fn, onError) {
  const b = el("button", { type: "button", "data-testid": testid }, label);
  b.addEventListener("click", async () => {
    b.disabled = true;
    try {
      await fn();
    } catch (err) {
      onError?.(err.message);
      const msg = document.querySelector("[data-testid=control-error]");
      if (msg) msg.textContent = err.message;
    } finally {
      b.disabled = false;
    }
  });
  return b;
}

// The control lease: who drives this robot, and the buttons to take, release or ask for it.
function controlRow(r, lease, onError) {
  const mine = lease && lease.holder === session.holder();
  const ago = lease ? `${Math.max(0, Math.round(Date.now() / 1000 - lease.last_drive))} s ago` : "";
  const row = el("div", { class: "control-row", "data-testid": "control" });
  if (!lease) {
    row.append(el("span", { "data-testid": "control-state" }, "Nobody drives it (the first drive takes control). "));
    if (session.allows("operator")) row.append(action("Take control", "take-control", () => api.takeControl(r.id), onError));
  } else if (mine) {
    row.append(el("span", { "data-testid": "control-state" }, "You have control · last command ",
      el("span", { "data-role": "lease-ago" }, ago), " "),
    action("Release control", "release-control", () => api.releaseControl(r.id), onError));
  } else {
    row.append(el("span", { "data-testid": "control-state" }, `Driven by ${lease.holder_name} · `,
      el("span", { "data-role": "lease-ago" }, ago), " "));
    if (session.allows("operator")) row.append(action("Request control", "request-control", () => api.requestControl(r.id), onError));
    if (session.allows("admin")) row.append(" ", action("Take over", "take-over", () => api.takeControl(r.id, true), onError));
  }
  row.append(el("div", { class: "reason", "data-testid": "control-error", role: "status" }));
  return row;
}

// An admin forgets a robot that is gone (DELETE /api/robots/{id}: its telemetry kept). A first press arms
// the button, a second one within 4 s forgets; only offline robots (an online one would come right back).
function forgetRow(r) {
  const note = el("div", { class: "reason", "data-testid": "forget-note", role: "status" });
  const button = el("button", { type: "button", "data-testid": "forget-robot" }, "Forget this robot");
  let armed = null;
  button.addEventListener("click", async () => {
    if (!armed) {
      button.textContent = "Press again to forget it";
      armed = setTimeout(() => { armed = null; button.textContent = "Forget this robot"; }, 4000);
      return;
    }
    clearTimeout(armed);
    button.disabled = true;
    try {
      await api.del(`/api/robots/${encodeURIComponent(r.id)}?telemetry=keep`);
      history.pushState({}, "", "/");
      dispatchEvent(new PopStateEvent("popstate"));
    } catch (err) {
      note.textContent = err.message;
      button.disabled = false;
    }
  });
  return el("div", { class: "forget-row" }, button, " ",
    el("span", { class: "muted" }, "out of the fleet list (its stored telemetry is kept)"), note);
}

// A request for control of a robot this tab drives: a notice with Grant, wherever the operator is.
store.on("lease_request", (msg) => {
  if (msg.holder !== session.holder()) return;
  const box = document.getElementById("lease-requests") ?? document.body.appendChild(
    el("div", { id: "lease-requests", class: "lease-requests", role: "alert", "aria-live": "assertive" }));
  const note = el("div", { class: "lease-request", "data-testid": "lease-request" },
    `${msg.from} asks for control of ${msg.robot_id}. `);
  const grant = action("Grant", "grant-control", async () => {
    await api.grantControl(msg.robot_id, msg.from_holder, msg.from);
    note.remove();
  });
  const dismiss = el("button", { type: "button", "data-testid": "dismiss-request" }, "Dismiss");
  dismiss.addEventListener("click", () => note.remove());
  note.append(grant, " ", dismiss);
  box.append(note);
});
