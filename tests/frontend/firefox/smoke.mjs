// The dashboard in Firefox: logs in, sees the robots on the map, holds the forward button of one robot
// and releases it, opens a camera robot's page and reads the AprilTag overlay's pixels. Prints one JSON
// line of what it saw; tests/frontend/test_firefox.py starts the server and robots and judges it.
// Firefox is Debian's firefox-esr, driven over WebDriver BiDi (puppeteer-core: no download, no geckodriver).
//
//   node smoke.mjs BASE_URL USERNAME PASSWORD DRIVE_ROBOT CAMERA_ROBOT
import { openFirefoxPage } from "./firefox.mjs";

const [base, username, password, driveRobot, cameraRobot] = process.argv.slice(2);
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

// x, y of every robot as the map's live layer drew it
const plotted = () => {
  const out = {};
  for (const [id, d] of Object.entries(window.fleetDebug?.mapRobots?.() ?? {})) out[id] = [d.x, d.y];
  return out;
};
// pixels of the overlay colour (cyan) on the camera overlay canvas
const overlayPixels = () => {
  const c = document.querySelector("[data-testid=overlay-canvas]");
  if (!c || !c.width) return 0;
  const d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
  let cyan = 0;
  for (let i = 0; i < d.length; i += 4) {
    if (d[i] < 60 && d[i + 1] > 180 && d[i + 2] > 200 && d[i + 3] > 200) cyan++;
  }
  return cyan;
};

async function visible(page, testid) {
  for (const h of await page.$$(`[data-testid=${testid}]`)) {
    if (await h.evaluate((e) => e.offsetParent !== null)) return h;
  }
  throw new Error(`no visible ${testid}`);
}

const out = { errors: [] };
const { browser, page } = await openFirefoxPage(out);
try {
  out.userAgent = await browser.userAgent();

  await page.goto(`${base}/`);
  await page.waitForSelector("[data-testid=login-username]", { timeout: 20000 });
  await page.type("[data-testid=login-username]", username);
  await page.type("[data-testid=login-password]", password);
  await page.click("[data-testid=login-submit]");
  await page.waitForFunction(() => window.fleetDebug && window.fleetDebug.wsConnected(), { timeout: 20000 });
  await page.waitForFunction(`Object.keys((${plotted})()).length >= 3`, { timeout: 20000 });
  out.plotted = await page.evaluate(plotted);

  // a locator finds the row again at the click: the list re-renders every second, and a handle taken
  // before could be detached by then ("Node is detached from document" under load)
  await page.locator(`[data-testid=robot-row-${driveRobot}]`).setTimeout(10000).click();
  await page.waitForFunction((id) => window.fleetDebug.selected() === id, { timeout: 10000 }, driveRobot);
  out.before = (await page.evaluate(plotted))[driveRobot];
  const box = await (await visible(page, "drive-forward")).boundingBox();
  await page.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
  await page.mouse.down();
  await sleep(1500);
  out.activeWhileHeld = await page.evaluate(() => window.fleetDebug.drive().active?.command ?? null);
  await page.mouse.up();
  out.activeAfterRelease = await page.evaluate(() => window.fleetDebug.drive().active?.command ?? null);
  await sleep(1200);
  out.after = (await page.evaluate(plotted))[driveRobot];
  out.commandSources = await page.evaluate(() => window.fleetDebug.commands().map((c) => c.source));

  await page.goto(`${base}/robots/${cameraRobot}`);
  await page.waitForFunction(() => window.fleetDebug?.camera().frames >= 5, { timeout: 20000 });
  // each new frame clears the overlay until its detections arrive: keep the count of a drawn one
  try {
    const drawn = await page.waitForFunction(
      `(() => { const n = (${overlayPixels})(); return n > 100 ? n : 0; })()`, { timeout: 15000 });
    out.overlayPixels = await drawn.jsonValue();
  } catch (e) {
    out.errors.push(`overlay: ${e}`);
    out.overlayPixels = await page.evaluate(overlayPixels);
  }
  out.cameraFrames = await page.evaluate(() => window.fleetDebug.camera().frames);
} catch (e) {
  out.errors.push(`smoke: ${e?.stack ?? e}`);
} finally {
  await browser.close();
}
console.log(JSON.stringify(out));
