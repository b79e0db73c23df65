// Client-side state: robots, recent positions (trails), latest telemetry per stream, commands, e-stop.
// Views subscribe to change notifications; nothing here touches the DOM.
// The store is the live data source of the map, the command log and the camera's detections; a run's
// replay (replaycursor.js) is the other one, with the same fields and topics (see docs/dashboard.md).

export const TRAIL_SECONDS = 10;
const TRAIL_STEP_S = 0.1;
const TRAIL_STEP_M = 0.005;
const MAX_COMMANDS = 3000; // raw commands kept: a held button sends 10 a second
const MAX_MISSION_EVENTS = 50;

/** on(topic, fn) -> unsubscribe, emit(topic, payload): a listener that throws does not stop the others. */
export class Emitter {
  constructor() {
    this.listeners = new Map(); // topic -> Set<fn>
  }

  on(topic, fn) {
    if (!this.listeners.has(topic)) this.listeners.set(topic, new Set());
    this.listeners.get(topic).add(fn);
    return () => this.listeners.get(topic).delete(fn);
  }

  emit(topic, payload) {
    for (const fn of this.listeners.get(topic) ?? []) {
      try {
        fn(payload);
      } catch (err) {
        console.error(`listener for ${topic} failed`, err);
      }
    }
  }
}

class Store extends Emitter {
  constructor() {
    super();
    this.robots = new Map(); // id -> RobotPublic (+ local fields)
    this.trails = new Map(); // id -> [{t, x, y}]
    this.latest = new Map(); // id -> {stream -> {ts, seq, data, received}}
    this.rates = new Map(); // id -> [received times] (for msg/s)
    this.geometry = new Map(); // id -> lighthouse geometry data
    this.commands = new Map(); // command id -> CommandPublic
    this.estop = { engaged: false };
    this.missions = new Map(); // id -> MissionPublic, as the server pushed it (/ws: snapshot, mission)
    this.swept = new Map(); // mission id -> the swept area's GeoJSON, as the server pushed it (mission_coverage)
    this.wsConnected = false;
    this.live = true;
  }

  /** The data source's clock (epoch s): now, live; the replay time in a replay. */
  now() {
    return Date.now() / 1000;
  }

  /** A robot an admin forgot: gone from the list, the map and the drive pad's choices. */
  forgetRobot(id) {
    this.robots.delete(id);
    this.trails.delete(id);
    this.emit("robots", id);
  }

  setRobot(robot) {
    const prev = this.robots.get(robot.id);
    this.robots.set(robot.id, { ...prev, ...robot });
    if (robot.position && !this.trails.has(robot.id)) {
      this.trails.set(robot.id, [{ t: robot.position.ts, x: robot.position.x, y: robot.position.y }]);
    }
    this.emit("robots", robot.id);
  }

  snapshot(robots, estop, missions = [], coverage = {}) {
    for (const r of robots) this.setRobot(r);
    if (estop) this.setEstop(estop);
    // the live missions as they are now (a reconnect may have missed their end); an ended one shown stays
    const ended = [...this.missions.values()].filter((m) => !["running", "paused"].includes(m.state));
    this.missions = new Map([...ended.slice(-1), ...missions].map((m) => [m.id, m]));
    for (const [id, geometry] of Object.entries(coverage)) this.swept.set(id, geometry);
    for (const id of this.swept.keys()) if (!this.missions.has(id)) this.swept.delete(id);
    this.emit("missions", null);
  }

  /** A mission the server pushed (any change); ended ones are kept only for the newest. */
  setMission(mission) {
    const events = this.missions.get(mission.id)?.events; // a push carries none: keep those heard
    this.missions.delete(mission.id);
    this.missions.set(mission.id, { ...mission, events: mission.events?.length ? mission.events : events ?? [] });
    for (const [id, m] of this.missions) {
      if (id !== mission.id && !["running", "paused", "draft"].includes(m.state)) {
        this.missions.delete(id);
        this.swept.delete(id);
      }
    }
    this.emit("missions", mission.id);
  }

  /** A mission's event (dropout, replan, too_close ...), pushed as it happens: the newest few are kept. */
  addMissionEvent(missionId, event) {
    const m = this.missions.get(missionId);
    if (!m) return;
    m.events = [...(m.events ?? []), event].slice(-MAX_MISSION_EVENTS);
    this.emit("missions", missionId);
  }

  /** A mission's swept area, pushed when it changed. */
  setSwept(msg) {
    this.swept.set(msg.mission_id, msg.geometry);
    const m = this.missions.get(msg.mission_id);
    if (m) m.covered_fraction = msg.covered_fraction;
    this.emit("missions", msg.mission_id);
  }

  setEstop(estop) {
    this.estop = estop;
    this.emit("estop", estop);
  }

  telemetry(msg) {
    const now = Date.now() / 1000;
    let streams = this.latest.get(msg.robot_id);
    if (!streams) this.latest.set(msg.robot_id, (streams = {}));
    streams[msg.stream] = { ts: msg.ts, seq: msg.seq, data: msg.data, received: now };
    let rate = this.rates.get(msg.robot_id);
    if (!rate) this.rates.set(msg.robot_id, (rate = []));
    rate.push(now);
    while (rate.length && rate[0] < now - 5) rate.shift();
    const robot = this.robots.get(msg.robot_id);
    if (robot) {
      robot.last_seen = Math.max(robot.last_seen ?? 0, now);
      robot.last_telemetry = now;
    }
    if (msg.stream === "position" && Number.isFinite(msg.data.x) && Number.isFinite(msg.data.y)) {
      if (robot) robot.position = { ...msg.data, ts: msg.ts };
      let trail = this.trails.get(msg.robot_id);
      if (!trail) this.trails.set(msg.robot_id, (trail = []));
      // thinned: a point per TRAIL_STEP_S while moving, one per second while still (20 Hz x 100 robots
      // x 10 s would be 20,000 points to redraw on every map frame)
      const last = trail[trail.length - 1];
      const dt = last ? msg.ts - last.t : Infinity;
      if (!last || dt < 0 || dt >= 1 ||
          (dt >= TRAIL_STEP_S && Math.hypot(msg.data.x - last.x, msg.data.y - last.y) >= TRAIL_STEP_M)) {
        trail.push({ t: msg.ts, x: msg.data.x, y: msg.data.y });
      }
      const cutoff = msg.ts - TRAIL_SECONDS;
      let drop = 0;
      while (drop < trail.length && trail[drop].t < cutoff) drop++;
      if (drop) trail.splice(0, drop);
    } else if (msg.stream === "lighthouse_geometry") {
      this.geometry.set(msg.robot_id, msg.data);
      this.emit("geometry", msg.robot_id);
    }
    this.emit("telemetry", msg);
  }

  rate(robotId) {
    const r = this.rates.get(robotId);
    if (!r || r.length < 2) return 0;
    const now = Date.now() / 1000;
    const recent = r.filter((t) => t > now - 5);
    return recent.length / Math.min(5, Math.max(1, now - recent[0]));
  }

  command(cmd) {
    this.commands.set(cmd.id, cmd);
    if (this.commands.size > MAX_COMMANDS) {
      const oldest = this.commands.keys().next().value;
      this.commands.delete(oldest);
    }
    this.emit("command", cmd);
  }

  /** Commands loaded from the history (GET .../commands): a command the live connection already gave
   * is kept as it is (it is as new or newer); past MAX_COMMANDS the oldest by time go. */
  addCommands(cmds) {
    for (const c of cmds) if (!this.commands.has(c.id)) this.commands.set(c.id, c);
    if (this.commands.size > MAX_COMMANDS) {
      const keep = [...this.commands.values()].sort((a, b) => a.ts - b.ts).slice(-MAX_COMMANDS);
      this.commands = new Map(keep.map((c) => [c.id, c]));
    }
    this.emit("commands", cmds.length);
  }

  isStale(robot) {
    if (!robot.online) return false;
    if (robot.stale) return true;
    const last = robot.last_telemetry ?? robot.position?.ts;
    return last !== undefined && Date.now() / 1000 - last > 2;
  }
}

export const store = new Store();
