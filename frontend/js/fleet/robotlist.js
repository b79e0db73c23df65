// The robot list: state, stale badge, last seen, message rate, legacy flag, sensors; sortable, filterable.
// Robots that are online (or stale) always come before offline ones, whatever the sort column, so gone
// robots from old state never bury live ones; "hide offline" (remembered in localStorage) drops them.
// Keyboard: the sort headers are buttons; a row is a Tab stop, Enter or Space selects it (again: opens it).
import { robotColor } from "../core/robotcolor.js";
import { store } from "../core/store.js";
import { ago, el } from "../core/util.js";

const STATE_ORDER = { online: 0, stale: 1, offline: 2 };
const HIDE_OFFLINE_KEY = "fleet.hideOffline";
const ARIA_SORT = { true: "ascending", false: "descending" };

function readHideOffline() {
  try {
    return localStorage.getItem(HIDE_OFFLINE_KEY) === "1";
  } catch {
    return false;
  }
}

export class RobotList {
  constructor(tbody, { onSelect, filterInput, header, countEl, hideOfflineInput }) {
    this.tbody = tbody;
    this.onSelect = onSelect;
    this.filter = "";
    this.sort = { key: "id", asc: true };
    this.selected = null;
    this.countEl = countEl;
    this.hideOffline = readHideOffline();
    if (hideOfflineInput) {
      hideOfflineInput.checked = this.hideOffline;
      hideOfflineInput.addEventListener("change", () => {
        this.hideOffline = hideOfflineInput.checked;
        try {
          localStorage.setItem(HIDE_OFFLINE_KEY, this.hideOffline ? "1" : "0");
        } catch {
          /* private mode: remembered for this page only */
        }
        this.render();
      });
    }
    filterInput.addEventListener("input", () => {
      this.filter = filterInput.value.trim().toLowerCase();
      this.render();
    });
    for (const th of header.querySelectorAll("th[data-sort]")) {
      th.addEventListener("click", () => {
        const key = th.dataset.sort;
        this.sort = { key, asc: this.sort.key === key ? !this.sort.asc : true };
        for (const o of header.querySelectorAll("th[data-sort]")) {
          o.classList.remove("sorted", "asc");
          o.setAttribute("aria-sort", "none");
        }
        th.classList.add("sorted");
        if (this.sort.asc) th.classList.add("asc");
        th.setAttribute("aria-sort", ARIA_SORT[this.sort.asc]);
        this.render();
      });
    }
    // delegated and on pointerdown: rows are re-rendered every second and a click must not fall between
    tbody.addEventListener("pointerdown", (ev) => {
      const row = ev.target.closest("tr[data-robot-id]");
      if (row) this.onSelect(row.dataset.robotId);
    });
    tbody.addEventListener("keydown", (ev) => {
      const row = ev.target.closest("tr[data-robot-id]");
      if (!row || ev.target !== row) return;
      if (ev.key === "Enter" || ev.key === " ") {
        ev.preventDefault();
        ev.stopPropagation(); // Space is "stop" for the drive keys: on a row it selects
        this.onSelect(row.dataset.robotId);
      } // arrows and WASD stay the drive keys
    });
    // robot updates come in bursts (100 robots refresh their status): one DOM rebuild per 250 ms at most
    store.on("robots", () => this.requestRender());
    setInterval(() => this.render(), 1000); // "3 s ago", rates and stale badges age by themselves
  }

  requestRender() {
    if (this.pending) return;
    this.pending = setTimeout(() => this.render(), 250);
  }

  state(robot) {
    if (!robot.online) return "offline";
    return store.isStale(robot) ? "stale" : "online";
  }

  select(id) {
    this.selected = id;
    this.render();
  }

  render() {
    clearTimeout(this.pending);
    this.pending = null;
    const robots = [...store.robots.values()].filter(
      (r) => (!this.hideOffline || r.online) && (!this.filter || r.id.toLowerCase().includes(this.filter) ||
        (r.capabilities?.sensors ?? []).some((s) => s.includes(this.filter))),
    );
    const { key, asc } = this.sort;
    const val = (r) =>
      key === "state" ? STATE_ORDER[this.state(r)] : key === "seen" ? -(r.last_seen ?? 0)
        : key === "rate" ? -store.rate(r.id) : r.id;
    robots.sort((a, b) => {
      if (key !== "state" && Boolean(a.online) !== Boolean(b.online)) return a.online ? -1 : 1;
      const va = val(a), vb = val(b);
      const c = va < vb ? -1 : va > vb ? 1 : a.id.localeCompare(b.id);
      return asc ? c : -c;
    });
    // the row with the keyboard focus keeps it across the rebuild
    const focused = this.tbody.contains(document.activeElement) ? document.activeElement.dataset.robotId : null;
    const rows = robots.map((r) => {
      const state = this.state(r);
      const sensors = r.capabilities?.sensors ?? [];
      const failing = Object.entries(r.sensors ?? {}).filter(([, s]) => s && s.ok === false).map(([n]) => n);
      const selected = r.id === this.selected;
      return el("tr", {
        class: [state === "offline" ? "offline" : "", selected ? "selected" : ""].join(" "),
        tabindex: "0",
        "aria-current": selected ? "true" : null,
        "aria-label": `${r.id}, ${state}${r.legacy ? ", legacy" : ""}${selected ? ", selected: Enter opens its page" : ""}`,
        dataset: { testid: `robot-row-${r.id}`, online: String(Boolean(r.online)), state, robotId: r.id },
      },
      el("td", {}, el("span", { class: "robot-dot", style: `background:${robotColor(r.id)}`, "aria-hidden": "true" }),
        el("strong", {}, r.id), r.legacy ? el("span", { class: "badge legacy" }, "legacy") : null,
        el("div", { class: "sensors" }, sensors.join(" · ") || "—",
          failing.length ? el("span", { class: "badge stale" }, `⚠ failing: ${failing.join(", ")}`) : null)),
      el("td", { class: "state" }, el("span", { class: `badge ${state}`, dataset: { testid: `state-${r.id}` } }, state),
        r.estop ? el("span", { class: "badge stopped" }, "e-stop") : null,
        ...Object.entries(r.alarms ?? {}).map(([kind, sev]) => el("span", {
          class: `badge ${sev === "critical" ? "stopped" : "stale"}`, dataset: { testid: `alarm-badge-${r.id}` },
        }, `⚠ ${kind.replaceAll("_", " ")}`)),
        r.ready === false && r.online ? el("span", { class: "badge not-ready", title: (r.not_ready_reasons ?? []).join("; "),
          dataset: { testid: `not-ready-${r.id}` } }, "not ready") : null),
      el("td", {}, ago(r.last_seen)),
      el("td", {}, `${store.rate(r.id).toFixed(0)}/s`));
    });
    this.tbody.replaceChildren(...rows);
    if (focused) this.tbody.querySelector(`tr[data-robot-id="${CSS.escape(focused)}"]`)?.focus();
    const online = [...store.robots.values()].filter((r) => r.online).length;
    const hidden = this.hideOffline ? store.robots.size - online : 0;
    this.countEl.textContent = `${online}/${store.robots.size} online${hidden ? ` · ${hidden} offline hidden` : ""}`;
  }
}
