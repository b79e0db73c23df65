// The live WebSocket: reconnects by itself with exponential backoff, resubscribes, and shows a banner
// while down. Every server frame is a JSON array of messages.
import { loginUrl } from "./api.js";
import { store } from "./store.js";

let socket = null;
let attempt = 0;
let subscription = { type: "subscribe", robots: ["*"], streams: ["*"] };
let bannerTimer = null;

function banner(show) {
  const el = document.getElementById("ws-banner");
  if (!el) return;
  clearTimeout(bannerTimer);
  if (show) {
    // a short blip (server restart) should not flash the banner
    bannerTimer = setTimeout(() => (el.hidden = false), 400);
  } else {
    el.hidden = true;
  }
}

function handle(msg) {
  switch (msg.type) {
    case "snapshot":
      store.snapshot(msg.robots, msg.estop, msg.missions, msg.coverage);
      break;
    case "robot":
      store.setRobot(msg.robot);
      break;
    case "telemetry":
      store.telemetry(msg);
      break;
    case "command":
      store.command(msg.command);
      break;
    case "estop":
      store.setEstop(msg.estop);
      break;
    case "mission":
      store.setMission(msg.mission);
      break;
    case "mission_coverage":
      store.setSwept(msg);
      break;
    case "mission_event":
      store.addMissionEvent(msg.mission_id, msg.event);
      break;
    case "robot_forgotten":
      store.forgetRobot(msg.robot_id);
      break;
    case "alarm":
      store.emit("alarm", msg.alarm);
      break;
    case "lease_request":
      store.emit("lease_request", msg);
      break;
    case "error":
      console.warn("server:", msg.detail);
      break;
    default:
      break;
  }
}

export function connect() {
  const proto = location.protocol === "https:" ? "wss" : "ws";
  const ws = new WebSocket(`${proto}://${location.host}/ws`);
  socket = ws;
  ws.onopen = () => {
    const el = document.getElementById("ws-banner");
    if (el) el.textContent = "disconnected — reconnecting…";
    store.wsConnected = true;
    ws.send(JSON.stringify(subscription));
    banner(false);
    store.emit("connection", true);
  };
  ws.onmessage = (ev) => {
    attempt = 0; // only a connection that delivers counts as up (a refusal is accepted, then closed)
    let batch;
    try {
      batch = JSON.parse(ev.data);
    } catch {
      return;
    }
    for (const msg of Array.isArray(batch) ? batch : [batch]) handle(msg);
  };
  ws.onclose = (ev) => {
    if (socket !== ws) return;
    store.wsConnected = false;
    store.emit("connection", false);
    banner(true);
    // 1008 = refused by policy: no or expired login (log in again), or e.g. a foreign Origin (keep trying)
    if (ev.code === 1008 && /auth|session|login/i.test(ev.reason)) {
      location.assign(loginUrl());
      return;
    }
    if (ev.code === 1008) {
      const el = document.getElementById("ws-banner");
      if (el) el.textContent = `Live connection refused: ${ev.reason || "policy"} — retrying…`;
    }
    const delay = Math.min(5000, 250 * 2 ** attempt) * (0.75 + Math.random() * 0.5);
    attempt += 1;
    setTimeout(connect, delay);
  };
  ws.onerror = () => ws.close();
}

export function resubscribe(robots = ["*"], streams = ["*"]) {
  subscription = { type: "subscribe", robots, streams };
  if (socket && socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify(subscription));
}
