// Builds the console's Plotly: the core (which always holds `scatter`) and the trace types in traces.json.
// Why: the full bundle is 4.8 MB and every page parses it; these three types are all the console draws.
// Same esbuild settings as plotly.js's own esbuild-config.js. Run with `make plotly-bundle`.
"use strict";
const fs = require("fs");
const path = require("path");
const esbuild = require("esbuild");
const { environmentPlugin } = require("esbuild-plugin-environment");
const { glsl } = require("esbuild-plugin-glsl");
const InlineCSSPlugin = require("esbuild-plugin-inline-css");

const traces = JSON.parse(fs.readFileSync(path.join(__dirname, "traces.json"), "utf8"));
const version = require("plotly.js/package.json").version;
const entry = [
  "var Plotly = require('plotly.js/lib/core');",
  `Plotly.register([${traces.filter((t) => t !== "scatter").map((t) => `require('plotly.js/lib/${t}')`).join(", ")}]);`,
  "module.exports = Plotly;",
].join("\n");

esbuild
  .build({
    stdin: { contents: entry, resolveDir: __dirname, sourcefile: "plotly-console.js" },
    outfile: path.join(__dirname, "..", "..", "frontend", "vendor", "plotly.min.js"),
    banner: { js: `/* plotly.js v${version} (MIT licence), custom bundle: ${traces.join(", ")}. Built by scripts/plotly-bundle. */` },
    format: "iife",
    globalName: "Plotly",
    bundle: true,
    minify: true,
    legalComments: "eof",
    plugins: [InlineCSSPlugin(), glsl({ minify: true }), environmentPlugin({ NODE_DEBUG: false })],
    alias: { regl: "@plotly/regl", stream: "stream-browserify" },
    define: { global: "window", "define.amd": "false" },
    target: "es2016",
    logLevel: "info",
  })
  .catch(() => process.exit(1));
