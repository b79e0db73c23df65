// Builds the console's Plotly: the core (which always holds `scatter`) and the trace types in traces.json.
// Why: the full bundle is 4.8 MB and every page parses it; these three types are all the console draws.
// Same esbuild settings as plotly.js's own esbuild-config.js. Run with `make plotly-bundle`.
// Strict, as plotly.js's own strict bundle (lib/index-strict.js): the server's Content-Security-Policy has no
// 'unsafe-eval' and no inline styles (backend/core/security.py). So the regl traces take their precompiled
// draw calls instead of compiling them with `Function`, and Plotly's styles come from vendor/plotly.css,
// which index.html links as `#plotly.js-style-global.no-inline-styles` (Plotly then inserts no <style>); one
// empty style attribute of the colour bar is patched away below.
"use strict";
const fs = require("fs");
const path = require("path");
const esbuild = require("esbuild");
const { environmentPlugin } = require("esbuild-plugin-environment");
const { glsl } = require("esbuild-plugin-glsl");
const InlineCSSPlugin = require("esbuild-plugin-inline-css");

const traces = JSON.parse(fs.readFileSync(path.join(__dirname, "traces.json"), "utf8"));
const version = require("plotly.js/package.json").version;
// the trace types that have a strict module (lib/index-strict.js requires these instead of lib/<type>)
const STRICT = { scattergl: "src/traces/scattergl/strict", scatterpolargl: "src/traces/scatterpolargl/strict",
  splom: "src/traces/splom/strict", parcoords: "src/traces/parcoords/strict" };
const vendor = path.join(__dirname, "..", "..", "frontend", "vendor");
const entry = [
  "var Plotly = require('plotly.js/lib/core');",
  `Plotly.register([${traces.filter((t) => t !== "scatter").map((t) => `require('plotly.js/${STRICT[t] ?? `lib/${t}`}')`).join(", ")}]);`,
  "module.exports = Plotly;",
].join("\n");
fs.copyFileSync(require.resolve("plotly.js/dist/plotly.css"), path.join(vendor, "plotly.css"));

// The one style attribute these traces still set as markup: the colour bar empties its fills' style with
// attr('style', ''), which the policy refuses even when empty (the history page's trajectories have a colour
// bar). Removing the attribute instead draws the same.
const colorbarWithoutStyleAttr = {
  name: "colorbar-without-style-attribute",
  setup(build) {
    build.onLoad({ filter: /plotly\.js[\\/]src[\\/]components[\\/]colorbar[\\/]draw\.js$/ }, async (args) => {
      const source = await fs.promises.readFile(args.path, "utf8");
      const patched = source.replaceAll(".attr('style', '')", ".attr('style', null)");
      if (patched === source) throw new Error(`${args.path} no longer empties a style attribute: drop this patch`);
      return { contents: patched, loader: "js" };
    });
  },
};

esbuild
  .build({
    stdin: { contents: entry, resolveDir: __dirname, sourcefile: "plotly-console.js" },
    outfile: path.join(vendor, "plotly.min.js"),
    banner: { js: `/* plotly.js v${version} (MIT licence), strict (no eval, no inline style), custom bundle: ${traces.join(", ")}. Built by scripts/plotly-bundle. */` },
    format: "iife",
    globalName: "Plotly",
    bundle: true,
    minify: true,
    legalComments: "eof",
    plugins: [colorbarWithoutStyleAttr, InlineCSSPlugin(), glsl({ minify: true }), environmentPlugin({ NODE_DEBUG: false })],
    alias: { regl: "@plotly/regl", stream: "stream-browserify" },
    define: { global: "window", "define.amd": "false" },
    target: "es2016",
    logLevel: "info",
  })
  .catch(() => process.exit(1));
