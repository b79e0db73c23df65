// Live camera of one robot: binary frames from /ws/camera/{id} (MFC1 header + JPEG), drawn on a canvas,
// with the apriltag detections of the same frame_seq drawn over it.
import { drawDetections } from "./apriltag_overlay.js";
import { store } from "./store.js";

const MAGIC = "MFC1";

export function parseFrame(buffer) {
  const view = new DataView(buffer);
  const magic = String.fromCharCode(...new Uint8Array(buffer, 0, 4));
  if (magic !== MAGIC) throw new Error("not a camera frame");
  const hlen = view.getUint32(4);
  const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 8, hlen)));
  return { header, jpeg: new Uint8Array(buffer, 8 + hlen) };
}

export class CameraView {
  constructor({ canvas, overlay, info, toggle }) {
    Object.assign(this, { canvas, overlay, info, toggle });
    this.robotId = null;
    this.ws = null;
    this.detections = new Map(); // frame_seq -> apriltag message data
    this.frames = [];
    this.lastHeader = null;
    this.stats = { frames: 0, overlays: 0 };
    this.infoSaysNoFrames = false;
    store.on("telemetry", (msg) => {
      if (msg.robot_id !== this.robotId || msg.stream !== "apriltag") return;
      this.detections.set(msg.data.frame_seq, msg.data);
      if (this.detections.size > 50) this.detections.delete(this.detections.keys().next().value);
      // detections usually arrive just after their frame: draw them on the frame already shown
      if (this.lastHeader && msg.data.frame_seq === this.lastHeader.frame_seq) this.drawOverlay(msg.data);
    });
    toggle.addEventListener("change", () => {
      if (!toggle.checked) overlay.getContext("2d").clearRect(0, 0, overlay.width, overlay.height);
      else if (this.lastHeader) this.drawOverlay(this.detections.get(this.lastHeader.frame_seq));
    });
    setInterval(() => this.showInfo(), 500);
  }

  open(robotId) {
    this.close();
    this.robotId = robotId;
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
      if (busy) return; // decoding the previous frame: skip, the next one is newer anyway
      busy = true;
      try {
        const { header, jpeg } = parseFrame(ev.data);
        const bitmap = await createImageBitmap(new Blob([jpeg], { type: "image/jpeg" }));
        if (this.canvas.width !== bitmap.width || this.canvas.height !== bitmap.height) {
          this.canvas.width = bitmap.width;
          this.canvas.height = bitmap.height;
        }
        this.canvas.getContext("2d").drawImage(bitmap, 0, 0);
        bitmap.close();
        this.lastHeader = header;
        this.stats.frames += 1;
        const now = Date.now() / 1000;
        this.frames.push({ t: now, age: now - header.ts });
        while (this.frames.length && this.frames[0].t < now - 2) this.frames.shift();
        this.drawOverlay(this.detections.get(header.frame_seq));
        // frames resumed after a gap: say so now rather than at the next 500 ms refresh
        if (this.infoSaysNoFrames) this.showInfo();
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

  drawOverlay(message) {
    const ctx = this.overlay.getContext("2d");
    if (!this.toggle.checked || !message) {
      ctx.clearRect(0, 0, this.overlay.width, this.overlay.height);
      return;
    }
    drawDetections(this.overlay, message);
    this.stats.overlays += 1;
  }

  showInfo() {
    if (!this.robotId) return;
    const now = Date.now() / 1000;
    const recent = this.frames.filter((f) => f.t > now - 2);
    this.infoSaysNoFrames = !recent.length;
    if (!recent.length) {
      this.info.textContent = this.lastHeader ? "no new frames" : "no frames";
      return;
    }
    const fps = recent.length / 2;
    const age = recent.reduce((s, f) => s + f.age, 0) / recent.length;
    this.info.textContent = `${fps.toFixed(1)} fps · age ${Math.max(0, age * 1000).toFixed(0)} ms · frame ${this.lastHeader.frame_seq}`;
  }

  close() {
    const ws = this.ws;
    this.ws = null;
    this.robotId = null;
    this.lastHeader = null;
    this.frames = [];
    this.detections.clear();
    if (ws) ws.close();
    this.canvas.getContext("2d").clearRect(0, 0, this.canvas.width, this.canvas.height);
    this.overlay.getContext("2d").clearRect(0, 0, this.overlay.width, this.overlay.height);
  }
}
