// Command log: the commands this server relayed (REST, keyboard, buttons, scripts) with their timeline in
// ms. A held drive button renews its command every 100 ms: those renewals collapse into one row ("held
// 2.0 s · 21× done"). The recent history comes from GET /api/robots/{id}/commands when the page opens, so a
// reload keeps the log; live commands and acks arrive over the WebSocket. A replay gives its own source (the
// run's commands up to the replay time, replaycursor.js): same fields (commands) and topics.
import { api } from "../core/api.js";
import { store } from "../core/store.js";
import { clock, el } from "../core/util.js";

const SHOW = 60;
/** Commands fetched per robot when the page opens (holds collapse: 300 is a few minutes of driving). */
const HISTORY_LIMIT = 300;
/** The fleet page loads the history of at most this many online robots. */
const FLEET_HISTORY_ROBOTS = 50;
/** Renewals of a hold come every 100 ms and each drives for 0.5 s: a longer pause is a new press. */
export const HOLD_GAP_S = 0.5;
const DRIVE = new Set(["move_forward", "move_backward", "turn_left", "turn_right"]);
const BAD = ["rejected", "expired", "timeout"];

const loaded = new Set();

/** Fetches a robot's recent commands once per page (again after a failure) into the store. */
async function loadRecent(robotId) {
  if (loaded.has(robotId)) return;
  loaded.add(robotId);
  try {
    store.addCommands(await api.get(`/api/robots/${encodeURIComponent(robotId)}/commands?limit=${HISTORY_LIMIT}`));
  } catch {
    loaded.delete(robotId); // try again the next time the robot shows up
  }
}

// after a lost connection the live feed missed whatever happened meanwhile: fetch the histories again
let connected = null;
store.on("connection", (up) => {
  if (up && connected === false) {
    const again = [...loaded];
    loaded.clear();
    again.forEach(loadRecent);
  }
  connected = up;
});

/** Rows of the log, newest first: a hold (a robot's consecutive renewals of the same drive command with
 * the same speed from the same source, each within HOLD_GAP_S of the one before) is one row. */
export function collapseHolds(cmds) {
  const rows = [];
  const openHold = new Map(); // robot id -> the row its next command may continue
  for (const c of [...cmds].sort((a, b) => a.ts - b.ts)) {
    const prev = openHold.get(c.robot_id);
    const last = prev?.cmds[prev.cmds.length - 1];
    if (prev && DRIVE.has(c.command) && c.command === last.command && c.source === last.source &&
        c.args?.speed === last.args?.speed && c.ts - last.ts <= HOLD_GAP_S) {
      prev.cmds.push(c);
      continue;
    }
    const row = { cmds: [c] };
    rows.push(row);
    openHold.set(c.robot_id, DRIVE.has(c.command) ? row : null);
  }
  return rows.reverse();
}

function timeline(cmd) {
  const steps = [el("span", { class: "st-sent" }, "sent")];
  for (const ack of cmd.acks ?? []) {
    const ms = Math.round((ack.received_ts - cmd.ts) * 1000);
    steps.push(" → ", el("span", { class: `st-${ack.status}`, title: ack.reason || "" }, `${ack.status} +${ms} ms`));
  }
  if (cmd.status === "timeout") steps.push(" → ", el("span", { class: "st-timeout" }, "timeout"));
  return steps;
}

/** "held 2.0 s · 20× done · 1× rejected": how long the button was held and how the renewals ended. */
function holdSummary(cmds) {
  const counts = new Map();
  for (const c of cmds) counts.set(c.status, (counts.get(c.status) ?? 0) + 1);
  const held = cmds[cmds.length - 1].ts - cmds[0].ts;
  return [el("span", { class: "held" }, `held ${held.toFixed(1)} s`),
    ...[...counts].flatMap(([status, n]) => [" · ", el("span", { class: `st-${status}` }, `${n}× ${status}`)])];
}

function rowStatus(cmds) {
  return cmds.find((c) => BAD.includes(c.status))?.status ?? cmds[cmds.length - 1].status;
}

export class CommandLog {
  /** ``source``: the live store (default) or a replay cursor; the recent history is fetched only live. */
  constructor(host, { robotId = null, testid = "command-log", source = store } = {}) {
    this.robotId = robotId;
    this.source = source;
    this.live = source === store;
    this.list = el("ul", { class: "log", "data-testid": testid });
    this.pending = false;
    host.replaceChildren(el("h3", {}, "Command log"), this.list);
    const later = () => {
      if (!this.pending) {
        this.pending = true;
        requestAnimationFrame(() => this.render());
      }
    };
    source.on("command", (cmd) => {
      if (!this.robotId || cmd.robot_id === this.robotId) later();
    });
    source.on("commands", later);
    if (!robotId && this.live) {
      // the fleet page: the history of the robots that are online, as the live snapshot names them
      store.on("robots", (id) => {
        if (!this.robotId && store.robots.get(id)?.online && loaded.size < FLEET_HISTORY_ROBOTS) loadRecent(id);
      });
    }
    this.render();
  }

  setRobot(id) {
    this.robotId = id;
    if (id && this.live) loadRecent(id);
    this.render();
  }

  render() {
    this.pending = false;
    const cmds = [...this.source.commands.values()].filter((c) => !this.robotId || c.robot_id === this.robotId);
    const rows = collapseHolds(cmds).slice(0, SHOW);
    this.list.replaceChildren(...rows.map(({ cmds: group }) => {
      const first = group[0], last = group[group.length - 1];
      const reasons = [...new Set(group.map((c) => c.reason).filter(Boolean))].join("; ");
      return el("li", { dataset: { id: last.id, firstId: first.id, status: rowStatus(group), command: first.command,
        robot: first.robot_id, source: first.source, count: String(group.length), hold: String(group.length > 1) },
      title: reasons },
      el("span", { class: "when" }, clock(first.ts)),
      el("span", {}, el("strong", {}, first.robot_id), ` ${first.command}`,
        first.args?.speed != null ? ` ${first.args.speed}` : "", el("span", { class: "muted" }, ` · ${first.source}`)),
      el("span", { class: "steps" }, ...(group.length > 1 ? holdSummary(group) : timeline(first))),
      // why a command was refused, inline: touch has no hover for the title
      reasons ? el("span", { class: "why", dataset: { testid: "command-reason" } }, reasons) : null);
    }));
    if (!rows.length) this.list.append(el("li", { class: "muted empty" }, "No commands yet."));
  }
}
