// Entry point: routing (/, /robots/{id}, /history, /users with history.pushState), live connection, views.
import { announce, focusableScrollRegions, labelDrivePads } from "./core/a11y.js";
import { setupAlarms } from "./core/alarms.js";
import { AuditView } from "./admin/audit.js";
import { BoundaryEditor } from "./map/boundaryedit.js";
import { CommandLog } from "./drive/commandlog.js";
import { DrivePad, driver } from "./drive/drive.js";
import { setupEstop } from "./drive/estop.js";
import { EventsPanel } from "./fleet/events.js";
import { FleetMap } from "./map/fleetmap.js";
import { GoToPanel } from "./drive/goto.js";
import { HistoryView } from "./history/history.js";
import { StickPanel } from "./drive/joystick.js";
import { MissionLayer } from "./missions/missionlayer.js";
import { MissionOverlay } from "./missions/missionpanel.js";
import { setupMissions } from "./missions/missions.js";
import { connect } from "./core/live.js";
import { RobotList } from "./fleet/robotlist.js";
import { RobotView } from "./robot/robotview.js";
import { RunsView } from "./runs/runs.js";
import { session, setupUserChip } from "./core/session.js";
import { normalizeSite } from "./map/sitedraw.js";
import { SiteEditor } from "./map/siteedit.js";
import { store, TRAIL_SECONDS } from "./core/store.js";
import { UsersView } from "./admin/users.js";
import { LegacyRobotsView } from "./admin/legacyrobots.js";

const debug = { frameTimes: [], renders: 0 };
let fleetMap, goToPanel, boundaryEditor, stickPanel, robotList, robotView, historyView, usersView, legacyView, auditView, runsView,
  missionsPanel;
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
    await Promise.all([usersView.open(), legacyView.load()]);
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
  const mission = path.match(/^\/missions(?:\/([^/]+))?$/);
  if (mission) {
    driver.release();
    show("missions");
    document.title = "Missions · Mollusca Fleet";
    missionsPanel ??= setupMissions();
    await missionsPanel?.open(mission[1] ? decodeURIComponent(mission[1]) : null);
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
  new MissionOverlay(document.getElementById("mission-overlay-host"), { map: document.getElementById("fleet-map") });
  new MissionLayer(fleetMap);
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
  legacyView = new LegacyRobotsView(document.getElementById("legacy-host"));
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
    // the selected robot's safety distance as last drawn, or null (nothing selected, or the layer off)
    mapSafety: () => (fleetMap.layers.shows("safety") ? fleetMap.safety.drawn : null),
    // the missions page's map: where a point of the pool (metres) is on screen, null before it is drawn
    missionsAt: (x, y) => missionsPanel?.clientAt(x, y) ?? null,
    // the missions page's rehearsal: busy, its seed, the predicted tracks held and as last drawn
    rehearsal: () => missionsPanel?.rehearsal.debug() ?? null,
    // the missions the live store holds (id -> state) and the swept areas pushed (id -> polygons)
    missions: () => ({ missions: Object.fromEntries([...store.missions].map(([id, m]) => [id, m.state])),
      swept: Object.fromEntries([...store.swept].map(([id, g]) => [id, g?.type ?? null])) }),
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
