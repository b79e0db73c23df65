// The robot list: state, stale badge, last seen, message rate, legacy flag, sensors; sortable, filterable.
import { store } from "./store.js";
import { ago, el } from "./util.js";

const STATE_ORDER = { online: 0, stale: 1, offline: 2 };

export class RobotList {
  constructor(tbody, { onSelect, filterInput, header, countEl }) {
    this.tbody = tbody;
    this.onSelect = onSelect;
    this.filter = "";
    this.sort = { key: "id", asc: true };
    this.selected = null;
    this.countEl = countEl;
    filterInput.addEventListener("input", () => {
      this.filter = filterInput.value.trim().toLowerCase();
      this.render();
    });
    for (const th of header.querySelectorAll("th[data-sort]")) {
      th.addEventListener("click", () => {
        const key = th.dataset.sort;
        this.sort = { key, asc: this.sort.key === key ? !this.sort.asc : true };
        for (const o of header.querySelectorAll("th")) o.classList.remove("sorted", "asc");
        th.classList.add("sorted");
        if (this.sort.asc) th.classList.add("asc");
        this.render();
      });
    }
    // delegated and on pointerdown: rows are re-rendered every second and a click must not fall between
    tbody.addEventListener("pointerdown", (ev) => {
      const row = ev.target.closest("tr[data-robot-id]");
      if (row) this.onSelect(row.dataset.robotId);
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
      (r) => !this.filter || r.id.toLowerCase().includes(this.filter) ||
        (r.capabilities?.sensors ?? []).some((s) => s.includes(this.filter)),
    );
    const { key, asc } = this.sort;
    const val = (r) =>
      key === "state" ? STATE_ORDER[this.state(r)] : key === "seen" ? -(r.last_seen ?? 0)
        : key === "rate" ? -store.rate(r.id) : r.id;
    robots.sort((a, b) => {
      const va = val(a), vb = val(b);
      const c = va < vb ? -1 : va > vb ? 1 : a.id.localeCompare(b.id);
      return asc ? c : -c;
    });
    const rows = robots.map((r) => {
      const state = this.state(r);
      const sensors = r.capabilities?.sensors ?? [];
      const failing = Object.entries(r.sensors ?? {}).filter(([, s]) => s && s.ok === false).map(([n]) => n);
      return el("tr", {
        class: [state === "offline" ? "offline" : "", r.id === this.selected ? "selected" : ""].join(" "),
        dataset: { testid: `robot-row-${r.id}`, online: String(Boolean(r.online)), state, robotId: r.id },
      },
      el("td", {}, el("strong", {}, r.id), r.legacy ? el("span", { class: "badge legacy" }, "legacy") : null,
        el("div", { class: "sensors" }, sensors.join(" · ") || "—",
          failing.length ? el("span", { class: "badge stale", title: "sensor failing" }, `⚠ ${failing.join(", ")}`) : null)),
      el("td", {}, el("span", { class: `badge ${state}`, dataset: { testid: `state-${r.id}` } }, state),
        r.estop ? el("span", { class: "badge stopped", title: "this robot reports its e-stop latched" }, "e-stop") : null),
      el("td", {}, ago(r.last_seen)),
      el("td", {}, `${store.rate(r.id).toFixed(0)}/s`));
    });
    this.tbody.replaceChildren(...rows);
    const online = [...store.robots.values()].filter((r) => r.online).length;
    this.countEl.textContent = `${online}/${store.robots.size} online`;
  }
}
