// The dashboard's rooms and what each may import (frontend/js; docs/dashboard.md, "Code layout"). Checked by
// `make lint` (dependency-cruiser), as import-linter checks the server's Python (.importlinter).
//
// core/      the api, the session, the live store and socket, theme, units: imports core only
// map/       the pool map and its site drawing and editing: core, map
// drive/     drive pad, stick, keys, gamepad, go-to, e-stop, command log: core, drive
// fleet/     the fleet page's robot list and events: core, fleet
// robot/     a robot's page, its camera and tags, its safety settings: core, robot, drive
// missions/  the missions page, the mission panel and map layer: core, missions, map
// runs/      runs, their replay and comparison: core, runs, map, drive, robot, fleet
// history/   the history page and its plots: core, history
// admin/     users and tokens, legacy robots, the audit trail: core, admin
// app.js, login.js, apidocs.js (entry points, one per page) may import anything; nothing imports them.
const ROOMS = {
  core: ["core"],
  map: ["core", "map"],
  drive: ["core", "drive"],
  fleet: ["core", "fleet"],
  robot: ["core", "robot", "drive"],
  missions: ["core", "missions", "map"],
  runs: ["core", "runs", "map", "drive", "robot", "fleet"],
  history: ["core", "history"],
  admin: ["core", "admin"],
};

const folderRules = Object.entries(ROOMS).map(([room, allowed]) => ({
  name: `${room}-imports-only-${allowed.join("-")}`,
  comment: `frontend/js/${room}/ may import ${allowed.join(", ")}`,
  severity: "error",
  from: { path: `^frontend/js/${room}/` },
  to: { path: "^frontend/js/", pathNot: `^frontend/js/(${allowed.join("|")})/` },
}));

module.exports = {
  forbidden: [
    ...folderRules,
    {
      name: "every-module-in-a-room",
      comment: "only the pages' entry points sit at the top of frontend/js; every other module is in a folder",
      severity: "error",
      from: {},
      to: { path: "^frontend/js/[^/]+[.]js$", pathNot: "^frontend/js/(app|login|apidocs)[.]js$" },
    },
    {
      name: "nothing-imports-an-entry-point",
      severity: "error",
      from: {},
      to: { path: "^frontend/js/(app|login|apidocs)[.]js$" },
    },
    {
      name: "no-circular",
      severity: "error",
      from: { path: "^frontend/js/" },
      to: { circular: true },
    },
    {
      name: "not-to-unresolvable",
      comment: "every import names a file that exists",
      severity: "error",
      from: {},
      to: { couldNotResolve: true },
    },
  ],
  options: {
    doNotFollow: { path: "node_modules" },
    exclude: { path: "^frontend/(vendor|js/vendor)/" },
  },
};
