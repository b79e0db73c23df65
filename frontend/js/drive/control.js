// Why a robot cannot be moved from this page right now (one sentence), or "" when it can. Shared by the
// drive pad, the stick (gamepad and touch joystick) and Go-to, so they refuse for the same reasons.
import { session } from "../core/session.js";
import { store } from "../core/store.js";

/** "" when ``command`` may move ``robotId`` from this page; otherwise the reason, ready to show inline. */
export function controlReason(robotId, command) {
  if (!robotId) return "Select a robot to drive it.";
  const r = store.robots.get(robotId);
  if (!r) return "Unknown robot.";
  if (!r.online) return `${robotId} is offline.`;
  if (!session.allows("operator")) return `Driving needs the operator role (you are ${session.me?.role}).`;
  if (store.estop?.engaged) return "E-stop engaged: release it to drive.";
  if (r.hold) return `Held by ${r.hold.source}: release the hold to drive.`;
  if (r.lease && r.lease.holder !== session.holder()) {
    return `Driven by ${r.lease.holder_name} · ${Math.max(0, Math.round(Date.now() / 1000 - r.lease.last_drive))} s ago: request control to drive.`;
  }
  const heldMate = (r.legacy_unit ?? []).map((id) => store.robots.get(id)).find((m) => m?.hold);
  if (heldMate) return `${heldMate.id} shares this robot's command topic and is held: release it to drive.`;
  if (r.capabilities && !r.capabilities.commands.includes(command)) {
    return command === "move_forward" ? "This robot takes no drive commands." : `This robot takes no ${command} commands.`;
  }
  return "";
}
