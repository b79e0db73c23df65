// Experiment runs (/runs, /runs/{id}): start and stop a run, find runs by name, tag or robot, see a run's
// summary and markers, add a marker (the button, or the M key anywhere in the dashboard while a run is
// recording), and export a run (MCAP, Parquet, zip) with a progress bar. Everything goes through the REST
// API (/api/runs), which checks the role and validates; its messages are shown next to what they concern.
// A run's page replays it on a map (runreplay.js).
import { announce } from "../core/a11y.js";
import { api, ApiError, CLIENT_ID } from "../core/api.js";
import { RunReplay } from "./runreplay.js";
import { separationLines } from "../core/separation.js";
import { session } from "../core/session.js";
import { store } from "../core/store.js";
import { el, textFieldFocused } from "../core/util.js";

const CONFIRM_MS = 4000;

function when(ts) {
  return ts == null ? "—" : new Date(ts * 1000).toLocaleString([], { hour12: false });
}

function duration(s) {
  if (s == null) return "—";
  const m = Math.floor(s / 60);
  return m ? `${m} min ${Math.round(s % 60)} s` : `${s.toFixed(1)} s`;
}

function runDuration(run) {
  return (run.ended_at ?? Date.now() / 1000) - run.started_at;
}

/** Add a marker to the one run recording now (the M key); returns the marker, or throws with why not. */
export async function markNow(text) {
  const running = await api.get("/api/runs?running=true");
  if (running.length === 0) throw new Error("no run is recording");
  if (running.length > 1) throw new Error("several runs are recording: add the marker on the run's page");
  return api.post(`/api/runs/${running[0].id}/markers`, { text: text || "marker (M key)" });
}

export class RunsView {
  constructor(host, { navigate }) {
    this.host = host;
    this.navigate = navigate;
    this.current = null; // the run shown in detail
    this.status = el("p", { class: "form-ok", role: "status", "data-testid": "runs-status" });
    this.error = el("p", { class: "form-error", "data-testid": "runs-error" });
    this.list = el("section", { class: "panel", "data-testid": "runs-list-panel" });
    this.detail = el("section", { class: "panel", "data-testid": "run-detail", hidden: true });
    this.replay = new RunReplay({
      onExportRange: (from, to, fmt) => this.current && this.download(this.current, fmt, this.progress, this.exportNote, { from, to }),
      onError: (err) => this.fail(err),
    });
    host.replaceChildren(this.status, this.error, this.buildStartForm(), this.list, this.detail);
    window.addEventListener("keydown", (ev) => this.onKey(ev));
    store.on("robots", () => this.fillRobots()); // the page opened before the fleet arrived
  }

  say(text) {
    this.error.textContent = "";
    this.status.textContent = text;
    announce(text);
  }

  fail(err) {
    this.status.textContent = "";
    this.error.textContent = err instanceof ApiError || err instanceof Error ? err.message : String(err);
  }

  // -- start a run ------------------------------------------------------------------------------------------
  buildStartForm() {
    this.robotSelect = el("select", { multiple: true, size: 3, "data-testid": "run-robots", "aria-label": "Robots to record" });
    const name = el("input", { type: "text", required: true, maxlength: 200, placeholder: "trial 7", "data-testid": "run-name" });
    const tags = el("input", { type: "text", placeholder: "current-on, 3 robots", "data-testid": "run-tags" });
    const rate = el("input", { type: "number", min: 0, max: 60, step: "any", value: 5, "data-testid": "run-frame-rate" });
    const form = el("form", { class: "panel run-start", "data-testid": "run-start-form" },
      el("h2", {}, "Start a run"),
      el("label", {}, "Name ", name),
      el("label", {}, "Tags ", tags),
      el("label", {}, "Robots (none selected: every online robot) ", this.robotSelect),
      el("label", {}, "Camera frames / s ", rate),
      el("button", { type: "submit", class: "btn primary", "data-testid": "run-start" }, "Start run"));
    form.addEventListener("submit", async (ev) => {
      ev.preventDefault();
      const robots = [...this.robotSelect.selectedOptions].map((o) => o.value);
      const body = {
        name: name.value.trim(),
        tags: tags.value.split(",").map((t) => t.trim()).filter(Boolean),
        frame_rate: Number(rate.value || 0),
      };
      if (robots.length) body.robots = robots;
      try {
        const run = await api.post("/api/runs", body);
        this.say(`Run ${run.id} “${run.name}” started: ${run.robots.join(", ")}.`);
        name.value = "";
        this.navigate(`/runs/${run.id}`);
      } catch (err) {
        this.fail(err);
      }
    });
    return form;
  }

  fillRobots() {
    const chosen = new Set([...this.robotSelect.selectedOptions].map((o) => o.value));
    const ids = [...store.robots.keys()].sort();
    if (ids.join("\n") === [...this.robotSelect.options].map((o) => o.value).join("\n")) return; // an open picker stays open
    this.robotSelect.replaceChildren(...ids.map((id) => el("option", { value: id, selected: chosen.has(id) }, id)));
  }

  // -- the list ------------------------------------------------------------------------------------------------
  async open(runId) {
    this.fillRobots();
    if (!this.list.firstChild) this.buildSearch();
    await this.search();
    if (runId == null) {
      this.current = null;
      this.detail.hidden = true;
    } else {
      await this.show(runId);
    }
  }

  buildSearch() {
    this.q = el("input", { type: "search", placeholder: "name", "aria-label": "Search runs by name", "data-testid": "runs-search-name" });
    this.qTag = el("input", { type: "search", placeholder: "tag", "aria-label": "Search runs by tag", "data-testid": "runs-search-tag" });
    this.qRobot = el("input", { type: "search", placeholder: "robot", "aria-label": "Search runs by robot", "data-testid": "runs-search-robot" });
    this.rows = el("tbody", { "data-testid": "run-rows" });
    const form = el("form", { class: "panel-head", role: "search" },
      el("h2", {}, "Runs"), this.q, this.qTag, this.qRobot,
      el("button", { type: "submit", class: "btn", "data-testid": "runs-search" }, "Search"));
    form.addEventListener("submit", (ev) => {
      ev.preventDefault();
      this.search();
    });
    this.list.replaceChildren(form, el("table", { class: "runs", "data-testid": "runs-table" },
      el("thead", {}, el("tr", {}, ...["Run", "Tags", "Robots", "Started", "Duration", ""].map((h) => el("th", {}, h)))),
      this.rows));
  }

  async search() {
    const params = new URLSearchParams();
    if (this.q.value.trim()) params.set("name", this.q.value.trim());
    if (this.qTag.value.trim()) params.set("tag", this.qTag.value.trim());
    if (this.qRobot.value.trim()) params.set("robot", this.qRobot.value.trim());
    try {
      const runs = await api.get(`/api/runs?${params}`);
      this.rows.replaceChildren(...runs.map((r) => this.row(r)));
      if (!runs.length) this.rows.append(el("tr", {}, el("td", { colspan: 6, class: "muted" }, "No runs found.")));
    } catch (err) {
      this.fail(err);
    }
  }

  row(run) {
    const link = el("a", { href: `/runs/${run.id}`, "data-link": true, "data-testid": "run-link" }, run.name);
    return el("tr", { "data-run-id": run.id },
      el("td", {}, link),
      el("td", {}, run.tags.join(", ")),
      el("td", {}, run.robots.join(", ")),
      el("td", {}, when(run.started_at)),
      el("td", {}, duration(runDuration(run))),
      el("td", {}, run.running ? el("span", { class: "badge live", "data-testid": "run-recording" }, "recording") : ""));
  }

  // -- one run ----------------------------------------------------------------------------------------------------
  async show(runId) {
    try {
      this.current = await api.get(`/api/runs/${runId}`);
    } catch (err) {
      this.current = null;
      this.detail.hidden = true;
      this.fail(err);
      return;
    }
    this.renderDetail();
  }

  renderDetail() {
    const run = this.current;
    const s = run.summary;
    const head = el("div", { class: "panel-head" },
      el("h2", { "data-testid": "run-title" }, `Run ${run.id}: ${run.name}`),
      run.running ? el("span", { class: "badge live" }, "recording") : el("span", { class: "muted" }, "ended"));
    const actions = el("div", { class: "run-actions" });
    if (run.running && session.allows("operator")) {
      actions.append(el("button", { type: "button", class: "btn", "data-testid": "run-stop", onclick: () => this.stop() }, "Stop run"));
    }
    const markerText = el("input", { type: "text", maxlength: 2000, placeholder: "tag 3 fell", "aria-label": "Marker text", "data-testid": "marker-text" });
    this.markerText = markerText;
    if (run.running && session.allows("operator")) {
      actions.append(markerText, el("button", {
        type: "button", class: "btn", title: "Mark this moment (M)", "data-testid": "marker-add",
        onclick: () => this.addMarker(markerText.value),
      }, "Add marker (M)"));
    }
    const progress = el("progress", { max: 1, value: 0, hidden: true, "data-testid": "export-progress" });
    const exportNote = el("span", { class: "muted", role: "status", "data-testid": "export-note" });
    for (const fmt of ["mcap", "parquet", "zip"]) {
      actions.append(el("button", {
        type: "button", class: "btn", "data-testid": `export-${fmt}`,
        onclick: () => this.download(run, fmt, progress, exportNote),
      }, `Export ${fmt === "mcap" ? "MCAP" : fmt === "zip" ? "zip" : "Parquet"}`));
    }
    actions.append(progress, exportNote);
    this.progress = progress;
    this.exportNote = exportNote;
    if (session.allows("admin")) actions.append(this.deleteButton(run));
    const streams = el("table", { class: "runs", "data-testid": "run-streams" },
      el("thead", {}, el("tr", {}, ...["Robot", "Stream", "Messages"].map((h) => el("th", {}, h)))),
      el("tbody", {}, ...s.messages.map((m) => el("tr", {}, el("td", {}, m.robot_id), el("td", {}, m.stream), el("td", {}, String(m.count))))));
    const facts = el("dl", { class: "details", "data-testid": "run-summary" },
      ...[
        ["Operator", run.operator],
        ["Mission", run.mission_id ? el("a", { href: `/missions/${encodeURIComponent(run.mission_id)}`, "data-link": true },
          `mission ${run.mission_id}`) : "—"],
        ["Started", when(run.started_at)],
        ["Ended", when(run.ended_at)],
        ["Duration", duration(s.duration_s)],
        ["Robots", s.robots.join(", ")],
        ["Tags", run.tags.join(", ") || "—"],
        ["Messages", String(s.messages_total)],
        ["Distance", Object.entries(s.distance_m).map(([r, d]) => `${r} ${d.toFixed(2)} m`).join(" · ") || "—"],
        ["Commands", String(s.commands)],
        ["E-stops", String(s.estops)],
        ["Alarms", String(s.alarms)],
        ["Separation", s.separation ? separationLines(s.separation, run.started_at).join("; ") : "—"],
        ["Gaps", s.gaps_missing ? `${s.gaps_missing} messages missing in ${s.gaps.length}${s.gaps_truncated ? "+" : ""} gaps` : "none"],
        ["Camera frames", `${run.frames} kept at ${run.frame_rate} / s${run.frames_stopped ? " — STOPPED: " + run.frames_stopped_reason : ""}`],
        ["Notes", run.notes || "—"],
      ].flatMap(([k, v]) => [el("dt", {}, k), el("dd", { "data-testid": `run-${k.toLowerCase().replace(/[^a-z]/g, "")}` }, v)]));
    const markers = el("ol", { class: "markers", "data-testid": "run-markers" },
      ...run.markers.map((m) => el("li", {}, `${when(m.ts)} ${m.robot_id ? `[${m.robot_id}] ` : ""}${m.text} — ${m.author}`)));
    this.detail.replaceChildren(head, actions, facts, el("h3", {}, "Markers"), markers, this.replay.host,
      el("h3", {}, "Streams"), streams);
    this.detail.hidden = false;
    this.replay.load(run).catch((err) => this.fail(err));
  }

  deleteButton(run) {
    let timer = null;
    const b = el("button", { type: "button", class: "btn small", "data-testid": "run-delete" }, "Delete run");
    b.addEventListener("click", async () => {
      if (!timer) {
        b.textContent = "Press again to delete";
        timer = setTimeout(() => { timer = null; b.textContent = "Delete run"; }, CONFIRM_MS);
        return;
      }
      clearTimeout(timer);
      try {
        await api.del(`/api/runs/${run.id}`);
        this.say(`Run ${run.id} deleted.`);
        this.navigate("/runs");
      } catch (err) {
        this.fail(err);
      }
    });
    return b;
  }

  async stop() {
    try {
      const run = await api.post(`/api/runs/${this.current.id}/stop`);
      this.say(`Run ${run.id} stopped after ${duration(runDuration(run))}.`);
      await this.open(run.id);
    } catch (err) {
      this.fail(err);
    }
  }

  async addMarker(text) {
    try {
      const marker = this.current?.running
        ? await api.post(`/api/runs/${this.current.id}/markers`, { text: text || "marker" })
        : await markNow(text);
      this.say(`Marker added to run ${marker.run_id}: ${marker.text}`);
      if (this.markerText) this.markerText.value = "";
      if (this.current && this.current.id === marker.run_id && !this.detail.hidden) await this.show(marker.run_id);
    } catch (err) {
      this.fail(err);
    }
  }

  onKey(ev) {
    if ((ev.key !== "m" && ev.key !== "M") || ev.ctrlKey || ev.metaKey || ev.altKey || ev.repeat) return;
    if (textFieldFocused() || !session.allows("operator")) return;
    ev.preventDefault();
    this.addMarker(this.markerText?.value ?? "");
  }

  /** Stream an export with a progress bar (the size is the server's estimate until it is done). */
  async download(run, fmt, progress, note, range = null) {
    progress.hidden = false;
    progress.value = 0;
    note.textContent = "exporting…";
    const params = new URLSearchParams({ format: fmt });
    if (range) {
      params.set("from", String(range.from));
      params.set("to", String(range.to));
    }
    try {
      const res = await fetch(`/api/runs/${run.id}/export?${params}`, {
        credentials: "same-origin", headers: { "X-Fleet-Client": CLIENT_ID },
      });
      if (!res.ok) {
        const body = await res.json().catch(() => ({}));
        throw new Error(body.detail ?? `export failed (${res.status})`);
      }
      const expected = Number(res.headers.get("X-Fleet-Expected-Bytes")) || 0;
      const reader = res.body.getReader();
      const chunks = [];
      let got = 0;
      for (;;) {
        const { done, value } = await reader.read();
        if (done) break;
        chunks.push(value);
        got += value.length;
        progress.value = expected ? Math.min(0.99, got / expected) : 0.5;
        note.textContent = `${(got / 1e6).toFixed(1)} MB`;
      }
      progress.value = 1;
      const ext = fmt === "parquet" ? "parquet.zip" : fmt;
      // the server names a range's file after it (run-7-12.0s-30.5s.mcap)
      const named = /filename="([^"]+)"/.exec(res.headers.get("Content-Disposition") ?? "");
      const filename = named ? named[1] : `run-${run.id}.${ext}`;
      const url = URL.createObjectURL(new Blob(chunks));
      const a = el("a", { href: url, download: filename, hidden: true });
      document.body.append(a);
      a.click();
      a.remove();
      setTimeout(() => URL.revokeObjectURL(url), 60_000);
      const running = res.headers.get("X-Fleet-Run-Running") === "true";
      note.textContent = `${filename}: ${(got / 1e6).toFixed(1)} MB${running ? " (still recording: up to now)" : ""}`;
      announce(`Export of run ${run.id} done.`);
    } catch (err) {
      note.textContent = `Export failed: ${err.message}`;
    }
  }
}
