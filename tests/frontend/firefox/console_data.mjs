// The console's data views in Firefox: the map (outline from the server, a colour per robot, readout), the
// command log (a hold is one row) and the history page (two robots, two fields; the x-y trajectory over
// the outline). Prints one JSON line of what it saw; tests/frontend/test_firefox_console_data.py starts the
// server and robots and judges it.
//
//   node console_data.mjs BASE_URL USERNAME PASSWORD ROBOT_A ROBOT_B START END
import { openFirefoxPage } from "./firefox.mjs";

const [base, username, password, robotA, robotB, start, end] = process.argv.slice(2);

const out = { errors: [] };
const { browser, page } = await openFirefoxPage(out);
try {

  await page.goto(`${base}/`);
  await page.waitForSelector("[data-testid=login-username]", { timeout: 20000 });
  await page.type("[data-testid=login-username]", username);
  await page.type("[data-testid=login-password]", password);
  await page.click("[data-testid=login-submit]");
  await page.waitForFunction(() => window.fleetDebug && window.fleetDebug.wsConnected(), { timeout: 20000 });
  await page.waitForFunction(() => Object.keys(window.fleetDebug.mapRobots()).length >= 2, { timeout: 20000 });

  // the map: the outline trace, each robot's drawn colour and the colour its id gives
  out.outline = await page.evaluate(() => {
    const t = document.getElementById("fleet-map").data.find((d) => d.name === "pool outline");
    return [Array.from(t.x), Array.from(t.y)];
  });
  out.colours = await page.evaluate(async (ids) => {
    const { robotColor } = await import("/assets/js/core/robotcolor.js");
    const live = document.querySelector("[data-testid=map-live]");
    const k = live.width / live.clientWidth;
    const rgb = (css) => {
      const c = document.createElement("canvas");
      c.width = c.height = 1;
      const g = c.getContext("2d");
      g.fillStyle = css;
      g.fillRect(0, 0, 1, 1);
      return Array.from(g.getImageData(0, 0, 1, 1).data).slice(0, 3);
    };
    const drawn = window.fleetDebug.mapRobots();
    return Object.fromEntries(ids.map((id) => [id, {
      want: rgb(robotColor(id)),
      got: Array.from(live.getContext("2d").getImageData(Math.round(drawn[id].px * k), Math.round(drawn[id].py * k), 1, 1).data).slice(0, 3),
    }]));
  }, [robotA, robotB]);

  // select a robot: the readout; hold forward for 15 renewals: one row in the log
  // a locator finds the row again at the click: the list re-renders every second, and a handle taken
  // before could be detached by then ("Node is detached from document" under load)
  await page.locator(`[data-testid=robot-row-${robotA}]`).click();
  await page.waitForFunction((id) => window.fleetDebug.selected() === id, {}, robotA);
  await page.waitForFunction(() => document.querySelector("[data-testid=map-readout]").dataset.robot, { timeout: 5000 });
  out.readout = await page.$eval("[data-testid=map-readout]", (e) => e.textContent);
  const box = await (await page.$("#drive-host [data-testid=drive-forward]")).boundingBox();
  await page.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
  await page.mouse.down();
  await page.waitForFunction(() => window.fleetDebug.drive().sent >= 15, { timeout: 10000 });
  await page.mouse.up();
  await page.waitForFunction(() => window.fleetDebug.drive().active === null);
  out.sent = await page.evaluate(() => window.fleetDebug.drive().sent);
  // every renewal and the stop acknowledged done: the hold's row says how many
  await page.waitForFunction((n) => {
    const cmds = window.fleetDebug.commands();
    return cmds.length === n && cmds.every((c) => c.status === "done");
  }, { timeout: 15000 }, out.sent);
  await page.waitForFunction(() => document.querySelector("[data-testid=command-log] li[data-command=move_forward]")
    ?.textContent.includes("done"), { timeout: 5000 });
  out.logRows = await page.$$eval("[data-testid=command-log] li", (rows) =>
    rows.map((r) => ({ command: r.dataset.command, count: r.dataset.count, text: r.textContent })));

  // history: two robots, two fields, one line each, in the robots' colours
  await page.goto(`${base}/history?robots=${robotA},${robotB}&stream=position&start=${start}&end=${end}&fields=x,y`);
  await page.waitForFunction(() => document.getElementById("history-chart").data?.length >= 4, { timeout: 20000 });
  out.timeTraces = await page.evaluate(() => document.getElementById("history-chart").data.map((t) => ({
    meta: t.meta, color: t.line?.color ?? null, n: t.y.length })));
  await page.click("[data-testid=history-mode-xy]");
  await page.waitForFunction(() => document.getElementById("history-chart").data?.some((t) => t.meta?.kind === "trajectory"),
    { timeout: 20000 });
  out.xyTraces = await page.evaluate(() => document.getElementById("history-chart").data.map((t) => ({
    meta: t.meta, n: t.x.length })));
} catch (e) {
  out.errors.push(`console_data: ${e?.stack ?? e}`);
} finally {
  await browser.close();
}
console.log(JSON.stringify(out));
