// A run's replay: its camera (runs/runreplay.js shows it beside the map).
import { api } from "../core/api.js";
import { lastAtOrBefore } from "./replaycursor.js";

/** The replay's camera: the robot's stored frame at the replay time. When each frame was taken is loaded
 * once (GET /api/runs/{id}/frames/times), so a seek knows its frame locally and asks for it (GET
 * /api/runs/{id}/frames?at=) only when it is another one; one request at a time, the newest time wins. */
export class ReplayCameraFeed {
  constructor() {
    this.runId = null;
    this.robotId = null;
    this.view = null;
    this.t = null;
    this.times = null; // [[ts, frame_seq]] of the robot's stored frames; a promise while loading
    this.busy = null; // the work in flight (a promise)
    this.again = false;
    this.note = "no frames";
    this.shown = null; // {ts, frame_seq} of the frame drawn
  }

  start(robotId, view) {
    this.robotId = robotId;
    this.view = view;
    this.shown = null;
    const q = new URLSearchParams({ robot: robotId });
    this.times = api.get(`/api/runs/${this.runId}/frames/times?${q}`).then((r) => r.frames, (err) => {
      this.note = `frames not loaded: ${err.message}`;
      return [];
    });
    if (this.t != null) this.show(this.t);
  }

  stop() {
    this.robotId = null;
    this.shown = null;
  }

  /** Show the frame at t; resolves when the newest asked-for time is drawn (or known to have none). */
  show(t) {
    this.t = t;
    if (this.busy) {
      this.again = true;
      return this.busy;
    }
    this.busy = (async () => {
      do {
        this.again = false;
        await this.fetch(this.t);
      } while (this.again);
      this.busy = null;
    })();
    return this.busy;
  }

  async fetch(t) {
    const robot = this.robotId, view = this.view;
    if (!robot || this.runId == null) return;
    const times = await this.times;
    if (robot !== this.robotId) return;
    const k = lastAtOrBefore(times, t, (f) => f[0]);
    if (k < 0) {
      this.shown = null;
      this.note = times.length ? "no frame yet at this time" : "this run kept no frames of this robot";
      view.generation += 1; // a decode under way is not drawn over the cleared canvas
      view.canvas.getContext("2d").clearRect(0, 0, view.canvas.width, view.canvas.height);
      delete view.canvas.dataset.frameSeq;
      delete view.canvas.dataset.ts;
      view.clearOverlay();
      view.showInfo();
      return;
    }
    const [ts, seq] = times[k];
    if (this.shown?.frame_seq === seq && this.shown.ts === ts) { // already drawn
      this.note = this.describeFrame(t, this.shown);
      return;
    }
    // asked for at the replay time (always inside the run), not at the frame's own ts: a run's first kept
    // frame may be stamped a little before the run started, and the server refuses times outside the run
    const frame = await api.get(`/api/runs/${this.runId}/frames?${new URLSearchParams({ robot, at: String(t) })}`)
      .catch((err) => {
        this.note = `frame not loaded: ${err.message}`;
        return null;
      });
    if (robot !== this.robotId || !frame) return;
    const bytes = Uint8Array.from(atob(frame.jpeg_base64), (ch) => ch.charCodeAt(0));
    view.noteDetections(frame.detections);
    if (await view.showFrame(bytes, { ts: frame.ts, frame_seq: frame.frame_seq })) {
      this.shown = { ts, frame_seq: frame.frame_seq, tags: frame.detections?.detections?.length ?? 0 };
      this.note = this.describeFrame(t, this.shown);
      view.showInfo();
    }
  }

  describeFrame(t, f) {
    return `frame ${f.frame_seq} · ${(t - f.ts).toFixed(2)} s before the replay time · ${f.tags} tag${f.tags === 1 ? "" : "s"}`;
  }

  describe() {
    return { text: this.note, none: !this.shown };
  }
}
