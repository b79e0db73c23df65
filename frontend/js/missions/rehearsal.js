// Rehearse (issue 32): the opened draft (or paused) mission run in a simulated twin of the fleet on the
// server (POST /api/missions/{id}/rehearsal, a few seconds), its predicted tracks drawn on the map
// (rehearsallayer.js) and its figures shown under the mission's controls (rehearsalfigures.js). One at a time:
// the button is disabled and says so while the twin runs. A second Rehearse replaces the tracks; Close, or
// opening another mission (or none), removes them. A mission keeps the summary of its latest rehearsal
// (``rehearsal``, no tracks): shown here until it ends, then its report sets it beside the outcome.
import { api } from "../core/api.js";
import { robotColor } from "../core/robotcolor.js";
import { session } from "../core/session.js";
import { el } from "../core/util.js";
import { PredictedLayer } from "./rehearsallayer.js";
import { figuresTable, speedLine } from "./rehearsalfigures.js";

const REHEARSABLE = ["draft", "paused"];
const ENDED = ["completed", "aborted", "failed"];

export class MissionRehearsal {
  /** ``map``: the missions page's FleetMap; ``say(text)``: where the mission's controls say a refusal. */
  constructor(map, { say }) {
    this.say = say;
    this.layer = new PredictedLayer(map);
    this.mission = null;
    this.answer = null; // the latest answer for the opened mission (with its tracks)
    this.closed = false; // Close pressed: the mission's kept summary stays hidden until the next rehearsal
    this.busy = false;
    // both labels in one grid cell, one of them invisible: the button keeps its width when it turns busy, so
    // the buttons beside it never move under a finger
    this.button = el("button", { type: "button", class: "btn btn-swap", "data-testid": "mission-rehearse",
      title: "Run this mission in a simulated twin of the fleet: predicted tracks and figures, moving no robot",
      onclick: () => this.rehearse() },
    el("span", { class: "swap-idle" }, "Rehearse"), el("span", { class: "swap-busy" }, "Rehearsing…"));
    // the heading and Close stay the same elements (a live region must be there before it changes; a button
    // replaced between a finger's down and up never gets its click); only the figures under them are rebuilt
    this.title = el("h3", { "aria-live": "polite", "data-testid": "rehearsal-title" });
    this.closeButton = el("button", { type: "button", class: "btn", "data-testid": "rehearsal-close",
      "aria-label": "Close the rehearsal", onclick: () => this.close() }, "Close");
    this.body = el("div", { class: "rehearsal-body" });
    this.block = el("section", { class: "rehearsal", "aria-label": "Rehearsal", "data-testid": "rehearsal", hidden: true },
      el("div", { class: "rehearsal-head" }, this.title, this.closeButton), this.body);
  }

  /** The mission opened changed (or was pushed a change): another mission, or none, drops the tracks. */
  show(m) {
    if (m?.id !== this.mission?.id) {
      this.answer = null;
      this.closed = false;
      this.layer.set(null);
    }
    this.mission = m;
    this.render();
  }

  async rehearse() {
    const m = this.mission;
    if (!m || this.busy) return;
    this.busy = true;
    this.say("");
    this.render();
    try {
      const answer = await api.post(`/api/missions/${encodeURIComponent(m.id)}/rehearsal`);
      if (!answer?.predicted) throw new Error("the server gave no prediction (timed out)");
      if (this.mission?.id !== m.id) return; // another mission was opened meanwhile: not drawn over it
      this.answer = answer;
      this.closed = false;
      this.layer.set(answer.predicted.tracks);
    } catch (err) {
      if (this.mission?.id === m.id) this.say(`Refused: ${err.message}`);
    } finally {
      this.busy = false;
      this.render();
    }
  }

  close() {
    this.answer = null;
    this.closed = true;
    this.layer.set(null);
    this.render();
  }

  render() {
    const m = this.mission;
    const can = session.allows("operator");
    this.button.disabled = !can || this.busy || !m || !REHEARSABLE.includes(m.state);
    this.button.setAttribute("aria-busy", String(this.busy));
    this.button.dataset.busy = String(this.busy);
    // after the run the report has the prediction beside the outcome; a fresh answer's tracks stay listed
    const kept = m && !ENDED.includes(m.state) && !this.closed ? m.rehearsal : null;
    const shown = this.answer ?? kept;
    this.block.hidden = !shown && !this.busy;
    this.block.dataset.state = this.busy ? "running" : this.answer ? "drawn" : shown ? "kept" : "none";
    const fresh = shown != null && shown === this.answer;
    const when = !fresh && shown?.at ? ` at ${new Date(shown.at * 1000).toLocaleTimeString([], { hour12: false })}` : "";
    // the heading says it is busy in place: no line comes and goes above Close or the figures
    this.title.textContent = this.busy ? "Rehearsing in the twin…" : fresh ? "Predicted" : `Latest rehearsal${when}`;
    this.closeButton.disabled = this.busy;
    // rebuilt only when what it shows changed: a mission's pushes come every second while it runs
    const key = JSON.stringify([m?.id, this.answer?.seed, this.answer?.took_s, kept?.at, kept?.seed]);
    if (key === this.shownKey) return;
    this.shownKey = key;
    this.body.replaceChildren(...(shown ? this.figures(shown, fresh) : []));
  }

  /** Its seed and speed, the tracks' legend (one line per robot, as drawn), the figures. */
  figures(r, fresh) {
    const speed = el("p", { class: "muted", "data-testid": "rehearsal-speed" }, speedLine(r));
    const perRobot = Object.entries(r.predicted?.per_robot ?? {}).sort(([a], [b]) => a.localeCompare(b));
    const legend = el("ul", { class: "rehearsal-legend", "data-testid": "rehearsal-legend" },
      ...perRobot.map(([id, p]) => el("li", { "data-robot": id },
        el("span", { class: `lg-line dotted${fresh ? "" : " faint"}`, style: `border-color:${robotColor(id)}` }),
        ` ${id} predicted: ${Number(p.distance_m).toFixed(2)} m in ${Math.round(p.duration_s)} s, ${p.status ?? "—"}`)));
    const note = fresh ? "" : el("p", { class: "muted" }, "Tracks are not kept: Rehearse again to draw them.");
    return [speed, legend, figuresTable(r), note];
  }

  /** What the layer and the block hold (window.fleetDebug.rehearsal()). */
  debug() {
    return { busy: this.busy, mission: this.mission?.id ?? null, seed: this.answer?.seed ?? null,
      tracks: this.layer.tracks.map((t) => ({ robotId: t.robotId, points: t.points.length, color: robotColor(t.robotId) })),
      drawn: this.layer.drawn };
  }
}
