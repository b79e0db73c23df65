// One way to open a page in headless Firefox (Debian's firefox-esr, no download) for the scripts beside
// this file: desktop size, every page error, console error and Content-Security-Policy violation collected
// in out.errors.
import puppeteer from "puppeteer-core";

export async function openFirefoxPage(out) {
  const browser = await puppeteer.launch({
    browser: "firefox",
    executablePath: process.env.FIREFOX ?? "/usr/bin/firefox-esr",
    headless: true,
  });
  try {
    const page = await browser.newPage();
    await page.setViewport({ width: 1280, height: 720 });
    page.on("pageerror", (e) => out.errors.push(String(e)));
    page.on("console", (m) => m.type() === "error" && out.errors.push(m.text()));
    // Firefox gives its own CSP report to no console event: the page makes it a console error (as the
    // Python tests' CSP_REPORTER does, tests/frontend/conftest.py)
    await page.evaluateOnNewDocument(() => document.addEventListener("securitypolicyviolation", (e) =>
      console.error(`CSP violation: ${e.effectiveDirective} ${e.blockedURI} ${e.sourceFile}:${e.lineNumber}`)));
    return { browser, page };
  } catch (err) {
    await browser.close(); // no Firefox left behind
    throw err;
  }
}
