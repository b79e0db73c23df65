// A run's replay as a data source: the same fields and topics as the live store (store.js), so that the
// live components draw it as they are (the map, the command log, the events). The run's data is loaded
// once (positions, goals, tag sightings, base stations, commands, events); a seek is then binary searches
// and slices in memory, and tells the views what changed:
// - "reset": the replay jumped (the map forgets the tags it saw; they are sent again for the new moment);
// - "telemetry": apriltag sightings up to the replay time (the map places the tags seen);
// - "robots": positions, trails and states at the replay time; "commands", "events": the lists up to it.
import { api } from "../core/api.js";
import { TAG_MEMORY_S } from "../map/fleetmap.js";
import { Emitter, TRAIL_SECONDS } from "../core/store.js";

/** Points per robot and stream loaded (the history API's bound); more are bucketed by the server. */
export const MAX_POINTS = 5000;
const TRAIL_STEP_S = 0.1; // as the live store thins its trails
const STALE_S = 2; // as the live store: no position for this long is stale
const GOAL_LIVE_S = 1; // as goto.js: a motion report older than this is no running goal
const JUMP_S = 1; // a seek further than this (or backwards) is a jump, not a step of the playback
const TAGS_PER_JUMP = 40; // sightings sent again after a jump, per robot (the newest)
const COMMANDS_PER_ROBOT = 1000;
const MAX_EVENTS = 10000;

/** Index of the last element whose time (key) is at or before ts (-1: none). */
export function lastAtOrBefore(items, ts, key = (p) => p.ts) {
  let lo = 0;
  let hi = items.length - 1;
  let found = -1;
  while (lo <= hi) {
    const mid = (lo + hi) >> 1;
    if (key(items[mid]) <= ts) {
      found = mid;
      lo = mid + 1;
    } else {
      hi = mid - 1;
    }
  }
  return found;
}

/** A stream of a run's robots between start and end (the history API, one request per robot). */
export async function loadStream(robots, stream, start, end, keep = () => true) {
  return new Map(await Promise.all(robots.map((id) => api.telemetry(id, {
    stream, start: String(start), end: String(end), max_points: MAX_POINTS,
  }).then((page) => [id, page.points.filter((p) => p.data && keep(p.data))]))));
}

const hasXY = (d) => Number.isFinite(d.x) && Number.isFinite(d.y);

export class ReplayCursor extends Emitter {
  constructor() {
    super();
    this.live = false;
    this.robots = new Map();
    this.trails = new Map();
    this.geometry = new Map();
    this.commands = new Map();
    this.t = 0;
    this.tracks = new Map(); // robot -> position points [{ts, data}]
    this.motion = new Map(); // robot -> motion reports
    this.sightings = new Map(); // robot -> apriltag messages
    this.geometries = new Map(); // robot -> lighthouse_geometry messages
    this.allCommands = []; // in time order
    this.allEvents = []; // in time order
    this.shownEvents = 0; // events at or before t
  }

  /** Load what the replay shows of a run; streams the run did not record are not asked for. */
  async load(run) {
    this.run = run;
    const start = run.started_at, end = run.ended_at ?? Date.now() / 1000;
    const recorded = new Set(run.summary.messages.map((m) => m.stream));
    const robots = run.robots;
    const maybe = (stream, keep) => (recorded.has(stream) ? loadStream(robots, stream, start, end, keep) : Promise.resolve(new Map()));
    const [tracks, motion, sightings, geometries, commands, events] = await Promise.all([
      loadStream(robots, "position", start, end, hasXY),
      maybe("motion"),
      maybe("apriltag", (d) => (d.detections ?? []).length > 0),
      maybe("lighthouse_geometry"),
      Promise.all(robots.map((id) => api.get(`/api/robots/${encodeURIComponent(id)}/commands?${new URLSearchParams({
        start: String(start), end: String(end), limit: String(COMMANDS_PER_ROBOT) })}`))),
      api.get(`/api/events?${new URLSearchParams({ start: String(start), end: String(end), limit: String(MAX_EVENTS) })}`),
    ]);
    Object.assign(this, { tracks, motion, sightings, geometries });
    this.allCommands = commands.flat().sort((a, b) => a.ts - b.ts);
    const mine = new Set(robots);
    this.allEvents = events.filter((e) => e.robot_id == null || mine.has(e.robot_id)).sort((a, b) => a.ts - b.ts);
    this.robots = new Map(robots.map((id) => [id, { id, online: true, estop: false, alarms: {}, position: undefined }]));
    this.trails = new Map();
    this.t = start;
    this.seek(start, { jump: true });
  }

  /** The replay time (the sources' clock: the map's tag memory and trail fading go by it). */
  now() {
    return this.t;
  }

  isStale(robot) {
    return robot.online && robot.position !== undefined && this.t - robot.position.ts > STALE_S;
  }

  /** A robot's pose at a time of the run (the tags it saw then are placed from it). */
  poseAt(id, ts) {
    const pts = this.tracks.get(id) ?? [];
    const k = lastAtOrBefore(pts, ts);
    return k < 0 ? null : { ...pts[k].data, ts: pts[k].ts };
  }

  /** The robot's goal running at the replay time, as its motion report says (goto.js's fromMotion shape). */
  motionAt(id) {
    const reports = this.motion.get(id) ?? [];
    const k = lastAtOrBefore(reports, this.t);
    if (k < 0 || this.t - reports[k].ts > GOAL_LIVE_S) return null;
    const d = reports[k].data;
    return d.state === "active" && (d.mode === "goto" || d.mode === "follow_path") ? d : null;
  }

  /** The robot's positions from ``from`` to the replay time (coverage, comparisons). */
  trackBetween(id, from, to = this.t) {
    const pts = this.tracks.get(id) ?? [];
    return pts.slice(lastAtOrBefore(pts, from - 1e-9) + 1, lastAtOrBefore(pts, to) + 1);
  }

  /** The newest events at or before the replay time, newest first. */
  events(limit) {
    const out = [];
    for (let i = this.shownEvents - 1; i >= 0 && out.length < limit; i--) out.push(this.allEvents[i]);
    return out;
  }

  /** Show the run at ``t``: every view that listens redraws. */
  seek(t, { jump = false } = {}) {
    const prev = this.t;
    this.t = t;
    const jumped = jump || t < prev || t - prev > JUMP_S;
    for (const [id, robot] of this.robots) {
      const pts = this.tracks.get(id) ?? [];
      const k = lastAtOrBefore(pts, t);
      robot.position = k < 0 ? undefined : { ...pts[k].data, ts: pts[k].ts };
      robot.online = this.stateAt(id, "online", "offline", true);
      robot.estop = this.stateAt(id, "estop", "estop_release", false);
      // the trail: the last TRAIL_SECONDS, a point per TRAIL_STEP_S at most (as the live store keeps it)
      const trail = [];
      for (let i = lastAtOrBefore(pts, t - TRAIL_SECONDS) + 1; i <= k; i++) {
        const last = trail[trail.length - 1];
        if (!last || pts[i].ts - last.t >= TRAIL_STEP_S || i === k) trail.push({ t: pts[i].ts, x: pts[i].data.x, y: pts[i].data.y });
      }
      this.trails.set(id, trail);
      // base stations: the robot's newest report, or its first one when none came before t (they do not move)
      const geos = this.geometries.get(id) ?? [];
      const g = geos[Math.max(0, lastAtOrBefore(geos, t))];
      if (g && this.geometry.get(id) !== g.data) {
        this.geometry.set(id, g.data);
        this.emit("geometry", id);
      }
    }
    if (jumped) this.emit("reset");
    // the tags seen: after a jump those of the tag memory before t, else those since the previous step
    const from = jumped ? t - TAG_MEMORY_S : prev;
    for (const [id, msgs] of this.sightings) {
      const hi = lastAtOrBefore(msgs, t);
      const lo = Math.max(lastAtOrBefore(msgs, from) + 1, jumped ? hi + 1 - TAGS_PER_JUMP : 0);
      for (let i = lo; i <= hi; i++) this.emit("telemetry", { robot_id: id, stream: "apriltag", ts: msgs[i].ts, data: msgs[i].data });
    }
    this.emit("robots");
    this.showCommands(t);
    const shown = lastAtOrBefore(this.allEvents, t) + 1;
    if (shown !== this.shownEvents || jumped) {
      this.shownEvents = shown;
      this.emit("events");
    }
  }

  /** Commands sent by t, each with the acks received by t (its status then, not its final one). */
  showCommands(t) {
    const k = lastAtOrBefore(this.allCommands, t);
    const commands = new Map();
    for (let i = 0; i <= k; i++) {
      const c = this.allCommands[i];
      const acks = (c.acks ?? []).filter((a) => a.received_ts <= t);
      const done = acks.length === (c.acks ?? []).length;
      commands.set(c.id, done ? c : { ...c, acks, status: acks.length ? acks[acks.length - 1].status : "sent" });
    }
    this.commands = commands;
    this.emit("commands", commands.size);
  }

  /** Whether the last of the robot's (or the fleet's) ``on`` / ``off`` events before t was ``on``. */
  stateAt(id, on, off, initial) {
    for (let i = lastAtOrBefore(this.allEvents, this.t); i >= 0; i--) {
      const e = this.allEvents[i];
      if ((e.robot_id === id || (e.robot_id == null && on === "estop")) && (e.kind === on || e.kind === off)) return e.kind === on;
    }
    return initial;
  }
}
