// A robot's camera on a canvas, with the AprilTag detections of the same frame_seq drawn over it. Where the
// frames come from is a feed: live (LiveCameraFeed: binary frames from /ws/camera/{id}, MFC1 header + JPEG,
// and the detections from the store's apriltag telemetry), or a run's replay (runreplay.js: the stored frame
// at the replay time, GET /api/runs/{id}/frames). The view decodes, draws, keeps the overlay toggle and counts.
import { drawDetections } from "./apriltag_overlay.js";
import { store } from "../core/store.js";

const MAGIC = "MFC1";
const KEEP_DETECTIONS = 50;
// A frame whose detections are still on the way keeps the outline of one at most this many frames older: a
// robot whose detector lags a frame behind (a loaded CPU) had every outline cleared by the next frame.
const OVERLAY_KEEP_FRAMES = 3;

export function parseFrame(buffer) {
  const view = new DataView(buffer);
  const magic = String.fromCharCode(...new Uint8Array(buffer, 0, 4));
  if (magic !== MAGIC) throw new Error("not a camera frame");
  const hlen = view.getUint32(4);
  const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 8, hlen)));
  return { header, jpeg: new Uint8Array(buffer, 8 + hlen) };
}

/** The live camera: frames over the camera WebSocket (reconnecting), detections from the live store. */
export class LiveCameraFeed {
  constructor() {
    this.ws = null;
    this.view = null;
    this.robotId = null;
    this.frames = []; // {t, age} of the frames of the last 2 s (fps and age)
    store.on("telemetry", (msg) => {
      if (this.view && msg.robot_id === this.robotId && msg.stream === "apriltag") this.view.noteDetections(msg.data);
    });
  }

  start(robotId, view) {
    this.stop();
    this.robotId = robotId;
    this.view = view;
    this.connect(0);
  }

  connect(attempt) {
    if (!this.robotId) return;
    const proto = location.protocol === "https:" ? "wss" : "ws";
    const ws = new WebSocket(`${proto}://${location.host}/ws/camera/${encodeURIComponent(this.robotId)}`);
    ws.binaryType = "arraybuffer";
    this.ws = ws;
    let busy = false;
    ws.onmessage = async (ev) => {
      if (busy || this.ws !== ws) return; // decoding the previous frame: skip, the next one is newer anyway
      busy = true;
      try {
        const { header, jpeg } = parseFrame(ev.data);
        if (!(await this.view.showFrame(jpeg, header))) return;
        const now = Date.now() / 1000;
        this.frames.push({ t: now, age: now - header.ts });
        while (this.frames.length && this.frames[0].t < now - 2) this.frames.shift();
        // frames resumed after a gap: say so now rather than at the next 500 ms refresh
        if (this.view.infoSaysNoFrames) this.view.showInfo();
      } catch (err) {
        console.warn("camera frame", err);
      } finally {
        busy = false;
      }
    };
    ws.onclose = () => {
      if (this.ws !== ws) return;
      setTimeout(() => this.ws === ws && this.connect(attempt + 1), Math.min(5000, 300 * 2 ** attempt));
    };
  }

  /** "5.0 fps · age 40 ms · frame 123", or that no frames come. */
  describe(view) {
    const now = Date.now() / 1000;
    const recent = this.frames.filter((f) => f.t > now - 2);
    if (!recent.length) return { text: view.lastHeader ? "no new frames" : "no frames", none: true };
    const fps = recent.length / 2;
    const age = recent.reduce((s, f) => s + f.age, 0) / recent.length;
    return { text: `${fps.toFixed(1)} fps · age ${Math.max(0, age * 1000).toFixed(0)} ms · frame ${view.lastHeader.frame_seq}`, none: false };
  }

  stop() {
    const ws = this.ws;
    this.ws = null;
    this.robotId = null;
    this.frames = [];
    if (ws) ws.close();
  }
}

export class CameraView {
  /** ``feed``: where frames come from (default: live); it calls showFrame and noteDetections. */
  constructor({ canvas, overlay, info, toggle, feed = new LiveCameraFeed() }) {
    Object.assign(this, { canvas, overlay, info, toggle, feed });
    this.robotId = null;
    this.detections = new Map(); // frame_seq -> apriltag message data
    this.lastHeader = null;
    this.stats = { frames: 0, overlays: 0 };
    this.infoSaysNoFrames = false;
    this.generation = 0; // a frame decoded for a robot no longer shown is not drawn
    toggle.addEventListener("change", () => {
      if (!toggle.checked) this.clearOverlay();
      else if (this.lastHeader) this.drawOverlay(this.detections.get(this.lastHeader.frame_seq));
    });
    setInterval(() => this.showInfo(), 500);
  }

  open(robotId) {
    this.close();
    this.robotId = robotId;
    this.feed.start(robotId, this);
  }

  /** Draw a JPEG (bytes) and its detections if known; false when it was not drawn (the robot changed). */
  async showFrame(jpeg, header) {
    const gen = this.generation;
    const bitmap = await createImageBitmap(new Blob([jpeg], { type: "image/jpeg" }));
    if (gen !== this.generation) {
      bitmap.close();
      return false;
    }
    if (this.canvas.width !== bitmap.width || this.canvas.height !== bitmap.height) {
      this.canvas.width = bitmap.width;
      this.canvas.height = bitmap.height;
    }
    this.canvas.getContext("2d").drawImage(bitmap, 0, 0);
    bitmap.close();
    this.lastHeader = header;
    this.canvas.dataset.frameSeq = String(header.frame_seq);
    this.canvas.dataset.ts = String(header.ts);
    this.stats.frames += 1;
    const own = this.detections.get(header.frame_seq);
    if (own || !this.overlayKept(header.frame_seq)) this.drawOverlay(own);
    return true;
  }

  /** The outline drawn is of a frame at most OVERLAY_KEEP_FRAMES before ``seq`` (none: false). */
  overlayKept(seq) {
    const drawn = this.overlay.dataset.frameSeq;
    if (drawn === undefined) return false;
    const behind = seq - Number(drawn);
    return behind >= 0 && behind <= OVERLAY_KEEP_FRAMES;
  }

  /** The detections of a frame; drawn at once when that frame is the one shown (they usually come after it),
   * or a few frames before it and newer than the outline drawn (a detector that lags behind the frames). */
  noteDetections(data) {
    if (!data) return;
    this.detections.set(data.frame_seq, data);
    if (this.detections.size > KEEP_DETECTIONS) this.detections.delete(this.detections.keys().next().value);
    if (!this.lastHeader) return;
    const shown = this.lastHeader.frame_seq;
    const behind = shown - data.frame_seq;
    const drawn = this.overlay.dataset.frameSeq;
    const newer = drawn === undefined || data.frame_seq > Number(drawn) || Number(drawn) > shown;
    if (behind === 0 || (behind > 0 && behind <= OVERLAY_KEEP_FRAMES && newer)) this.drawOverlay(data);
  }

  clearOverlay() {
    this.overlay.getContext("2d").clearRect(0, 0, this.overlay.width, this.overlay.height);
    delete this.overlay.dataset.frameSeq;
    this.overlay.dataset.tags = "";
  }

  drawOverlay(message) {
    if (!this.toggle.checked || !message) {
      this.clearOverlay();
      return;
    }
    drawDetections(this.overlay, message);
    // what is drawn, for tests and screen readers: the frame and the tag ids
    this.overlay.dataset.frameSeq = String(message.frame_seq);
    this.overlay.dataset.tags = (message.detections ?? []).map((d) => d.tag_id).join(",");
    this.stats.overlays += 1;
  }

  showInfo() {
    if (!this.robotId) return;
    const { text, none } = this.feed.describe(this);
    this.infoSaysNoFrames = none;
    this.info.textContent = text;
  }

  close() {
    this.feed.stop();
    this.generation += 1;
    this.robotId = null;
    this.lastHeader = null;
    this.detections.clear();
    delete this.canvas.dataset.frameSeq;
    delete this.canvas.dataset.ts;
    this.canvas.getContext("2d").clearRect(0, 0, this.canvas.width, this.canvas.height);
    this.clearOverlay();
  }
}
