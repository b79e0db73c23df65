// Debian's firefox-esr for Python tests: one headless Firefox (puppeteer-core over WebDriver BiDi) that
// tests/frontend/firefox_page.py drives with one JSON request per stdin line, answered by one JSON line
// on stdout ({id, ok, value} or {id, ok: false, error}). It keeps, per page, what the Chromium tests'
// Recorder keeps: requests, failed responses (>= 400) and console / page errors.
//
//   node bridge.mjs          (FIREFOX: the browser binary, default /usr/bin/firefox-esr)
import { createInterface } from "node:readline";
import puppeteer from "puppeteer-core";

const browser = await puppeteer.launch({
  browser: "firefox",
  executablePath: process.env.FIREFOX ?? "/usr/bin/firefox-esr",
  headless: true,
  // the light theme, whatever the machine's (the Chromium tests ask for it per page; Firefox has no such call)
  extraPrefsFirefox: { "layout.css.prefers-color-scheme.content-override": 1 },
});
const pages = new Map(); // id -> { page, context, requests, failures, errors }
let nextPage = 1;

function pageOf(id) {
  const p = pages.get(id);
  if (!p) throw new Error(`no page ${id}`);
  return p;
}

const ops = {
  async userAgent() {
    return browser.userAgent();
  },
  /** A page in a fresh browser context (its own cookies), with the given viewport and cookies; ``init``: a
   *  script run in every document it loads before the document's own (firefox_page.py: the CSP reporter). */
  async newPage({ width, height, cookies, init }) {
    const context = await browser.createBrowserContext();
    if (cookies?.length) await context.setCookie(...cookies);
    const page = await context.newPage();
    await page.setViewport({ width, height });
    if (init) await page.evaluateOnNewDocument(init);
    const rec = { page, context, requests: [], failures: [], errors: [] };
    page.on("request", (r) => rec.requests.push(r.url()));
    page.on("response", (r) => r.status() >= 400 && rec.failures.push(`${r.status()} ${r.url()}`));
    page.on("pageerror", (e) => rec.errors.push(String(e)));
    page.on("console", (m) => m.type() === "error" && rec.errors.push(m.text()));
    const id = nextPage++;
    pages.set(id, rec);
    return id;
  },
  async closePage({ page }) {
    const p = pages.get(page);
    pages.delete(page);
    if (p) await p.context.close();
  },
  async recorder({ page }) {
    const { requests, failures, errors } = pageOf(page);
    return { requests, failures, errors };
  },
  async goto({ page, url }) {
    await pageOf(page).page.goto(url, { waitUntil: "load" });
  },
  async reload({ page }) {
    await pageOf(page).page.reload({ waitUntil: "load" });
  },
  async goBack({ page }) {
    await pageOf(page).page.goBack({ waitUntil: "load" });
  },
  async url({ page }) {
    return pageOf(page).page.url();
  },
  async content({ page }) {
    return pageOf(page).page.content();
  },
  /** Evaluates an expression string in the page (awaited; the value comes back as JSON). */
  async evaluate({ page, expression }) {
    return pageOf(page).page.evaluate(expression);
  },
  async mouse({ page, action, x, y }) {
    const m = pageOf(page).page.mouse;
    if (action === "move") await m.move(x, y);
    else if (action === "down") await m.down();
    else if (action === "up") await m.up();
    else if (action === "click") await m.click(x, y);
    else throw new Error(`mouse ${action}?`);
  },
  async keyboard({ page, action, key, text }) {
    const k = pageOf(page).page.keyboard;
    if (action === "down") await k.down(key);
    else if (action === "up") await k.up(key);
    else if (action === "press") await k.press(key);
    else if (action === "type") await k.type(text);
    else throw new Error(`keyboard ${action}?`);
  },
  async screenshot({ page, path }) {
    await pageOf(page).page.screenshot({ path });
  },
  async cookies({ page }) {
    return pageOf(page).page.cookies();
  },
};

const lines = createInterface({ input: process.stdin });
const reply = (msg) => process.stdout.write(JSON.stringify(msg) + "\n");
reply({ id: 0, ok: true, value: await browser.userAgent() }); // ready
for await (const line of lines) {
  if (!line.trim()) continue;
  const { id, op, args } = JSON.parse(line);
  if (op === "quit") break;
  try {
    const value = await ops[op](args ?? {});
    reply({ id, ok: true, value: value === undefined ? null : value });
  } catch (e) {
    reply({ id, ok: false, error: String(e?.stack ?? e) });
  }
}
await browser.close();
