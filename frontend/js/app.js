// Entry point: routing (/, /robots/{id}, /history with history.pushState), live connection, views.
import { CommandLog } from "./commandlog.js";
import { DrivePad, driver } from "./drive.js";
import { setupEstop } from "./estop.js";
import { EventsPanel } from "./events.js";
import { FleetMap } from "./fleetmap.js";
import { HistoryView } from "./history.js";
import { connect } from "./live.js";
import { RobotList } from "./robotlist.js";
import { RobotView } from "./robotview.js";
import { session, setupUserChip } from "./session.js";
import { store, TRAIL_SECONDS } from "./store.js";

const debug = { frameTimes: [], renders: 0 };
let fleetMap, robotList, robotView, historyView;
let selected = null;

function selectRobot(id) {
  selected = id;
  driver.setRobot(id);
  fleetMap.select(id);
  robotList.select(id);
}

function openRobot(id) {
  navigate(`/robots/${encodeURIComponent(id)}`);
}

function show(view) {
  for (const v of ["fleet", "robot", "history"]) document.getElementById(`view-${v}`).hidden = v !== view;
  for (const a of document.querySelectorAll("[data-nav]")) a.classList.toggle("active", a.dataset.nav === view);
}

async function route() {
  const path = location.pathname;
  const m = path.match(/^\/robots\/([^/]+)$/);
  if (m) {
    const id = decodeURIComponent(m[1]);
    show("robot");
    selectRobot(id);
    robotView.open(id);
    document.title = `${id} · Mollusca Fleet`;
    return;
  }
  robotView.close();
  if (path === "/history") {
    driver.release(); // no driving from a page without a drive pad
    show("history");
    document.title = "History · Mollusca Fleet";
    await historyView.open(new URLSearchParams(location.search));
    return;
  }
  show("fleet");
  document.title = "Mollusca Fleet";
  if (selected) driver.setRobot(selected);
  window.dispatchEvent(new Event("resize")); // plotly sizes itself to a now-visible container
}

export function navigate(url) {
  if (url !== location.pathname + location.search) history.pushState({}, "", url);
  route();
}

function setupLinks() {
  document.addEventListener("click", (ev) => {
    const a = ev.target.closest("a[data-link]");
    if (!a || ev.ctrlKey || ev.metaKey || ev.shiftKey || ev.button !== 0) return;
    ev.preventDefault();
    navigate(a.getAttribute("href"));
  });
  window.addEventListener("popstate", route);
}

function setupConnectionBadge() {
  const conn = document.getElementById("conn");
  const update = (up) => {
    conn.textContent = up ? "live" : "offline";
    conn.className = `conn ${up ? "up" : "down"}`;
  };
  store.on("connection", update);
}

function main() {
  document.getElementById("trail-s").textContent = String(TRAIL_SECONDS);
  fleetMap = new FleetMap(document.getElementById("fleet-map"), { onSelect: (id) => selectRobot(id), debug });
  robotList = new RobotList(document.getElementById("robot-rows"), {
    onSelect: (id) => (id === selected ? openRobot(id) : selectRobot(id)),
    filterInput: document.getElementById("robot-filter"),
    header: document.querySelector("table.robots thead"),
    countEl: document.getElementById("robot-count"),
  });
  new DrivePad(document.getElementById("drive-host"));
  new CommandLog(document.getElementById("log-host"));
  new EventsPanel(document.getElementById("events-host"));
  robotView = new RobotView();
  historyView = new HistoryView();
  setupEstop();
  setupLinks();
  setupConnectionBadge();
  setupUserChip();
  session.load();
  // the fleet map's selection: a double click on a list row or a second click opens the robot page
  document.getElementById("robot-rows").addEventListener("dblclick", (ev) => {
    const row = ev.target.closest("tr[data-robot-id]");
    if (row) openRobot(row.dataset.robotId);
  });
  connect();
  route();
  window.fleetDebug = {
    robots: () => Object.fromEntries([...store.robots].map(([id, r]) => [id, structuredClone(r)])),
    wsConnected: () => store.wsConnected,
    selected: () => selected,
    frameTimes: debug.frameTimes,
    renders: () => debug.renders,
    staticRenders: () => debug.staticRenders ?? 0,
    mapRobots: () => fleetMap.drawnRobots(),
    drive: () => ({ robot: driver.robotId, active: driver.active, sent: driver.sent }),
    camera: () => ({ ...robotView.camera.stats, last: robotView.camera.lastHeader }),
    commands: () => [...store.commands.values()],
    estop: () => store.estop,
    me: () => session.me,
  };
}

main();
