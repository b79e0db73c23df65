// Colours for plotly, read from the CSS variables so charts follow the light/dark theme.
export function themeColors() {
  const css = getComputedStyle(document.documentElement);
  const v = (name) => css.getPropertyValue(name).trim();
  return {
    bg: v("--panel"), fg: v("--fg"), muted: v("--muted"), grid: v("--border"),
    accent: v("--accent"), warn: v("--warn"), bad: v("--bad"), ok: v("--ok"), offline: v("--offline"),
  };
}

export function baseLayout(extra = {}) {
  const c = themeColors();
  return {
    paper_bgcolor: c.bg, plot_bgcolor: c.bg, font: { color: c.fg, size: 11 },
    margin: { l: 44, r: 10, t: 10, b: 36 }, showlegend: false,
    xaxis: { gridcolor: c.grid, zerolinecolor: c.grid },
    yaxis: { gridcolor: c.grid, zerolinecolor: c.grid },
    ...extra,
  };
}

export const plotConfig = { displaylogo: false, responsive: true, modeBarButtonsToRemove: ["select2d", "lasso2d"] };

/** Calls ``fn`` when the system switches between light and dark (charts re-read the colours). */
export function onThemeChange(fn) {
  window.matchMedia?.("(prefers-color-scheme: dark)").addEventListener?.("change", () => fn());
}
