// Command log: every command from any client (REST, keyboard, buttons) with its timeline in ms.
import { store } from "./store.js";
import { clock, el } from "./util.js";

const SHOW = 60;

function timeline(cmd) {
  const steps = [el("span", { class: "st-sent" }, "sent")];
  for (const ack of cmd.acks ?? []) {
    const ms = Math.round((ack.received_ts - cmd.ts) * 1000);
    steps.push(" → ", el("span", { class: `st-${ack.status}`, title: ack.reason || "" }, `${ack.status} +${ms} ms`));
  }
  if (cmd.status === "timeout") steps.push(" → ", el("span", { class: "st-timeout" }, "timeout"));
  return steps;
}

export class CommandLog {
  constructor(host, { robotId = null, testid = "command-log" } = {}) {
    this.robotId = robotId;
    this.list = el("ul", { class: "log", "data-testid": testid });
    this.pending = false;
    host.replaceChildren(el("h3", {}, "Command log"), this.list);
    store.on("command", (cmd) => {
      if (this.robotId && cmd.robot_id !== this.robotId) return;
      if (!this.pending) {
        this.pending = true;
        requestAnimationFrame(() => this.render());
      }
    });
    this.render();
  }

  setRobot(id) {
    this.robotId = id;
    this.render();
  }

  render() {
    this.pending = false;
    const cmds = [...store.commands.values()]
      .filter((c) => !this.robotId || c.robot_id === this.robotId)
      .sort((a, b) => b.ts - a.ts)
      .slice(0, SHOW);
    this.list.replaceChildren(
      ...cmds.map((c) =>
        el("li", { dataset: { id: c.id, status: c.status, command: c.command, robot: c.robot_id, source: c.source }, title: c.reason || "" },
          el("span", { class: "when" }, clock(c.ts)),
          el("span", {}, el("strong", {}, c.robot_id), ` ${c.command}`, c.args?.speed != null ? ` ${c.args.speed}` : "",
            el("span", { class: "muted" }, ` · ${c.source}`)),
          el("span", { class: "steps" }, ...timeline(c)))),
    );
    if (!cmds.length) this.list.append(el("li", { class: "muted empty" }, "No commands yet."));
  }
}
