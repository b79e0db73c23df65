// Entry point: routing (/, /robots/{id}, /history, /users with history.pushState), live connection, views.
import { announce, focusableScrollRegions, labelDrivePads } from "./a11y.js";
import { setupAlarms } from "./alarms.js";
import { AuditView } from "./audit.js";
import { BoundaryEditor } from "./boundaryedit.js";
import { CommandLog } from "./commandlog.js";
import { DrivePad, driver } from "./drive.js";
import { setupEstop } from "./estop.js";
import { EventsPanel } from "./events.js";
import { FleetMap } from "./fleetmap.js";
import { GoToPanel } from "./goto.js";
import { HistoryView } from "./history.js";
import { StickPanel } from "./joystick.js";
import { MissionOverlay } from "./missionpanel.js";
import { setupMissions } from "./missions.js";
import { connect } from "./live.js";
import { RobotList } from "./robotlist.js";
import { RobotView } from "./robotview.js";
import { RunsView } from "./runs.js";
import { session, setupUserChip } from "./session.js";
import { normalizeSite } from "./sitedraw.js";
import { SiteEditor } from "./siteedit.js";
import { store, TRAIL_SECONDS } from "./store.js";
import { UsersView } from "./users.js";

const debug = { frameTimes: [], renders: 0 };
let fleetMap, goToPanel, boundaryEditor, stickPanel, robotList, robotView, historyView, usersView, auditView, runsView, missionsPanel;
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
  for (const v of ["fleet", "robot", "history", "users", "audit", "runs", "missions"]) {
    document.getElementById(`view-${v}`).hidden = v !== view;
  }
  for (const a of document.querySelectorAll("[data-nav]")) {
    a.classList.toggle("active", a.dataset.nav === view);
    if (a.dataset.nav === view) a.setAttribute("aria-current", "page");
    else a.removeAttribute("aria-current");
  }
  setMenu(false);
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
  if (path === "/users") {
    driver.release();
    show("users");
    document.title = "Users & tokens · Mollusca Fleet";
    await usersView.open();
    return;
  }
  if (path === "/audit") {
    driver.release();
    show("audit");
    document.title = "Audit trail · Mollusca Fleet";
    await auditView.open();
    return;
  }
  const run = path.match(/^\/runs(?:\/(\d+))?$/);
  if (run) {
    driver.release();
    show("runs");
    document.title = "Runs · Mollusca Fleet";
    await runsView.open(run[1] ? Number(run[1]) : null);
    return;
  }
  if (path === "/missions") {
    driver.release();
    show("missions");
    document.title = "Missions · Mollusca Fleet";
    missionsPanel ??= setupMissions();
    return;
  }
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
  let was = null;
  const update = (up) => {
    conn.textContent = up ? "live" : "offline";
    conn.className = `conn ${up ? "up" : "down"}`;
    if (was !== null && was !== up) announce(up ? "Live connection restored." : "Live connection lost; reconnecting.");
    was = up;
  };
  store.on("connection", update);
}

/** Phones: the navigation folds into a menu behind one button. */
function setMenu(open) {
  const toggle = document.getElementById("nav-toggle");
  document.getElementById("menu").classList.toggle("open", open);
  toggle.setAttribute("aria-expanded", String(open));
}

function setupMenu() {
  const toggle = document.getElementById("nav-toggle");
  toggle.addEventListener("click", () => setMenu(toggle.getAttribute("aria-expanded") !== "true"));
  store.on("session", (me) => {
    for (const nav of ["users", "audit"]) document.querySelector(`[data-nav=${nav}]`).hidden = !(me && me.role === "admin");
  });
}

function main() {
  document.getElementById("trail-s").textContent = String(TRAIL_SECONDS);
  fleetMap = new FleetMap(document.getElementById("fleet-map"), { onSelect: (id) => selectRobot(id), debug });
  robotList = new RobotList(document.getElementById("robot-rows"), {
    onSelect: (id) => (id === selected ? openRobot(id) : selectRobot(id)),
    filterInput: document.getElementById("robot-filter"),
    header: document.querySelector("table.robots thead"),
    countEl: document.getElementById("robot-count"),
    hideOfflineInput: document.getElementById("hide-offline"),
  });
  new DrivePad(document.getElementById("drive-host"));
  const siteEditor = new SiteEditor(document.getElementById("site-edit-host"), {
    onSaved: (site) => fleetMap.setSite(normalizeSite(site)),
  });
  stickPanel = new StickPanel(document.getElementById("stick-host"));
  goToPanel = new GoToPanel(document.getElementById("goto-host"), fleetMap);
  new MissionOverlay(document.getElementById("mission-overlay-host"), {
    map: document.getElementById("fleet-map"),
    isVisible: () => !document.getElementById("view-fleet").hidden,
  });
  boundaryEditor = new BoundaryEditor(document.getElementById("boundary-edit-host"), fleetMap, {
    onStart: () => goToPanel.arm("off"), // a stray click while editing never moves a robot
    onEnd: () => goToPanel.render(),
    onSaved: (site) => {
      fleetMap.setSite(normalizeSite(site));
      siteEditor.show(site);
    },
  });
  new CommandLog(document.getElementById("log-host"));
  new EventsPanel(document.getElementById("events-host"));
  robotView = new RobotView();
  historyView = new HistoryView();
  usersView = new UsersView(document.getElementById("users-host"));
  auditView = new AuditView(document.getElementById("audit-host"));
  runsView = new RunsView(document.getElementById("runs-host"), { navigate });
  labelDrivePads();
  focusableScrollRegions();
  setupEstop();
  setupAlarms();
  setupMenu();
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
    mapLabels: () => fleetMap.drawnLabels(),
    mapLastTap: () => fleetMap.lastTap ?? null,
    drive: () => ({ robot: driver.robotId, active: driver.active, sent: driver.sent }),
    stick: () => stickPanel.state(),
    goto: () => goToPanel.state(),
    boundaryEdit: () => boundaryEditor.state(),
    mapSite: () => fleetMap.site,
    mapPoint: (x, y) => fleetMap.toClient(x, y),
    // the runs page's replay: a seek that resolves once every view shows it; what its map drew
    replaySeek: (t) => runsView.replay.seekAndSettle(t),
    replayMapRobots: () => runsView.replay.map.drawnRobots(),
    camera: () => ({ ...robotView.camera.stats, last: robotView.camera.lastHeader }),
    commands: () => [...store.commands.values()],
    estop: () => store.estop,
    me: () => session.me,
  };
}

main();
