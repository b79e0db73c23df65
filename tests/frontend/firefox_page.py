"""Debian's firefox-esr behind the subset of Playwright's sync Page API that the Chromium tests use, so the
same test functions run in Gecko (Playwright's own Firefox is a patched build that cannot be downloaded
here). One headless Firefox per module, driven over WebDriver BiDi by puppeteer-core in a Node process
(tests/frontend/firefox/bridge.mjs), one JSON line per call.

What it does like Playwright: locators are lazy and re-resolved on every call; actions wait until the one
element is visible, enabled, still for two polls and the topmost at its centre, then send real mouse and
keyboard input; ``wait_for*`` poll until their timeout (30 s by default). What it does differently, said
where it matters: no touch (``tap`` is a mouse click, and only pages made with ``touch_as_mouse`` accept
touch options); ``expect_download`` captures the file the page hands to an ``<a download>`` (its Blob
read in the page) instead of the browser's download; ``expect_response`` fetches the matching request's
URL again in the page (same cookies) for its body."""

from __future__ import annotations

import contextlib
import json
import re
import shutil
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urljoin

import pytest

from tests.support.priority import below_the_robots
from tests.support.procs import base_env

HERE = Path(__file__).resolve().parent / "firefox"
FIREFOX = "/usr/bin/firefox-esr"
SCREENSHOTS = Path(__file__).resolve().parents[2] / "docs" / "screenshots"
TIMEOUT_MS = 30000
POLL_S = 0.05

# (steps) -> elements: the locator's chain of steps resolved in the page, in document order
_RESOLVE = r"""function resolve(steps) {
  const visible = (e) => { const r = e.getBoundingClientRect();
    return r.width > 0 && r.height > 0 && getComputedStyle(e).visibility !== 'hidden'; };
  const norm = (s) => (s ?? '').replace(/\s+/g, ' ').trim().toLowerCase();
  const ROLES = { button: 'button, input[type=button], input[type=submit], input[type=reset], [role=button]',
    link: 'a[href], [role=link]', heading: 'h1, h2, h3, h4, h5, h6, [role=heading]',
    checkbox: 'input[type=checkbox], [role=checkbox]',
    textbox: 'input:not([type]), input[type=text], textarea, [role=textbox]',
    combobox: 'select, [role=combobox]', row: 'tr, [role=row]', table: 'table, [role=table]' };
  const roleOf = (e, role) => (e.getAttribute('role') ?? role) === role;
  const nameOf = (e) => {
    const by = e.getAttribute('aria-labelledby');
    if (by) return norm(by.split(/\s+/).map((id) => document.getElementById(id)?.textContent ?? '').join(' '));
    if (e.getAttribute('aria-label')) return norm(e.getAttribute('aria-label'));
    if (e.labels?.length) return norm([...e.labels].map((l) => l.textContent).join(' '));
    const text = norm(e.tagName === 'INPUT' ? e.value : e.textContent);
    return text || norm(e.getAttribute('title'));
  };
  const exposed = (e) => e.getClientRects().length > 0 && getComputedStyle(e).visibility !== 'hidden'
    && !e.closest('[aria-hidden=true]');
  let els = [document];
  for (const [kind, a, b, c] of steps) {
    if (kind === 'css' || kind === 'role') {
      const sel = kind === 'css' ? a.replace(/:visible\b/g, '') : ROLES[a];
      if (!sel) throw new Error(`role ${a} is not known to firefox_page.py`);
      const found = new Set();
      for (const root of els) for (const e of root.querySelectorAll(sel)) found.add(e);
      els = [...found].sort((x, y) => (x.compareDocumentPosition(y) & Node.DOCUMENT_POSITION_FOLLOWING ? -1 : 1));
      if (kind === 'css' && /:visible\b/.test(a)) els = els.filter(visible);
      if (kind === 'role') {
        els = els.filter((e) => roleOf(e, a) && exposed(e));
        if (b != null) els = els.filter((e) => (c ? nameOf(e) === norm(b) : nameOf(e).includes(norm(b))));
      }
    } else if (kind === 'text') {
      els = els.filter((e) => norm(e.textContent).includes(norm(a)));
    } else if (kind === 'and') {
      const other = new Set(resolve(a));
      els = els.filter((e) => other.has(e));
    } else if (kind === 'nth') {
      const e = a < 0 ? els[els.length + a] : els[a];
      els = e ? [e] : [];
    } else throw new Error(`step ${kind}?`);
  }
  return els.filter((e) => e !== document);
}"""

# Playwright's hit-target check at the moment of input: the first pointer event of a click must reach the
# element (or its label); when it reaches something else, the whole click is kept from the page and the
# caller tries again. None when no event came (the page navigated first).
_GUARD_CLICK = r"""(els) => {
  const e = els[0];
  const own = (t) => t === e || e.contains(t) || (e.labels && [...e.labels].some((l) => l.contains(t)));
  const types = ['pointerdown', 'mousedown', 'pointerup', 'mouseup', 'click'];
  const state = {verdict: null};
  const guard = (ev) => {
    if (state.verdict === null)
      state.verdict = own(ev.target) ? 'hit' : (ev.target.outerHTML || String(ev.target)).slice(0, 120);
    if (state.verdict !== 'hit') { ev.preventDefault(); ev.stopImmediatePropagation(); }
  };
  for (const t of types) window.addEventListener(t, guard, true);
  const remove = () => { for (const t of types) window.removeEventListener(t, guard, true); };
  window.__fleetClickGuard = {state, remove};
  return true;
}"""
_GUARD_VERDICT = """() => { const g = window.__fleetClickGuard; if (!g) return null;
  g.remove(); delete window.__fleetClickGuard; return g.state.verdict; }"""

# what an action needs of its element, measured in the page: null while it cannot act yet
_ACTIONABLE = r"""(els, [scroll, needEnabled]) => {
  if (els.length !== 1) return {count: els.length};
  const e = els[0];
  const r0 = e.getBoundingClientRect();
  if (!(r0.width > 0 && r0.height > 0) || getComputedStyle(e).visibility === 'hidden')
    return {count: 1, why: 'not visible'};
  if (needEnabled && (e.disabled || e.closest('fieldset:disabled') || e.getAttribute('aria-disabled') === 'true'))
    return {count: 1, why: 'disabled'};
  if (scroll && (r0.top < 0 || r0.left < 0 || r0.bottom > innerHeight || r0.right > innerWidth))
    e.scrollIntoView({block: 'center', inline: 'center'});
  const r = e.getBoundingClientRect();
  const x = r.x + r.width / 2, y = r.y + r.height / 2;
  const hit = document.elementFromPoint(x, y);
  const on = hit && (hit === e || e.contains(hit) || (e.labels && [...e.labels].some((l) => l.contains(hit))));
  return {count: 1, x, y, box: [r.x, r.y, r.width, r.height], on, hit: hit ? hit.outerHTML.slice(0, 120) : null};
}"""


def _call_expression(expression: str, arg: Any) -> str:
    """Playwright's evaluate rule: a function is called with ``arg``, anything else is the value."""
    return (
        f"(async () => {{ const __f = ({expression}\n); "
        f"return typeof __f === 'function' ? await __f({json.dumps(arg)}) : await __f; }})()"
    )


class FirefoxError(AssertionError):
    """A Firefox call failed or a wait ran out (an AssertionError, as a failed expectation is)."""


class FirefoxBrowser:
    """One headless firefox-esr (tests/frontend/firefox/bridge.mjs) for a module's tests."""

    def __init__(self, tmp_home: Path) -> None:
        node = shutil.which("node")
        if node is None:
            pytest.fail("node missing: scripts/ensure-system-deps.sh installs nodejs")
        if not (HERE / "node_modules" / "puppeteer-core").is_dir():
            pytest.fail("puppeteer-core missing: `make test` runs npm ci in tests/frontend/firefox")
        if not Path(FIREFOX).exists():
            pytest.fail("firefox-esr missing: scripts/ensure-system-deps.sh installs it")
        self._proc = subprocess.Popen(
            below_the_robots([node, str(HERE / "bridge.mjs")]),  # tests/support/priority.py
            cwd=HERE,
            env=base_env(FIREFOX=FIREFOX, HOME=str(tmp_home)),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            bufsize=1,
        )
        self._next = 1
        self.user_agent: str = self._read(0)

    def _read(self, want: int) -> Any:
        assert self._proc.stdout is not None
        line = self._proc.stdout.readline()
        if not line:
            err = self._proc.stderr.read() if self._proc.stderr else ""
            raise FirefoxError(f"the Firefox bridge exited: {err[-3000:]}")
        msg = json.loads(line)
        assert msg["id"] == want, msg
        if not msg["ok"]:
            raise FirefoxError(msg["error"])
        return msg["value"]

    def call(self, op: str, **args: Any) -> Any:
        assert self._proc.stdin is not None
        rid, self._next = self._next, self._next + 1
        self._proc.stdin.write(json.dumps({"id": rid, "op": op, "args": args}) + "\n")
        self._proc.stdin.flush()
        return self._read(rid)

    def close(self) -> None:
        if self._proc.poll() is None:
            with contextlib.suppress(OSError):
                assert self._proc.stdin is not None
                self._proc.stdin.write(json.dumps({"id": -1, "op": "quit"}) + "\n")
                self._proc.stdin.close()
            try:
                self._proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()


class FirefoxRecorder:
    """The Chromium tests' Recorder, read from the bridge when asked."""

    def __init__(self, page: FirefoxPage) -> None:
        self._page = page

    def _get(self, key: str) -> list[str]:
        return list(self._page._browser.call("recorder", page=self._page._id)[key])

    @property
    def requests(self) -> list[str]:
        return self._get("requests")

    @property
    def failures(self) -> list[str]:
        return self._get("failures")

    @property
    def console_errors(self) -> list[str]:
        return self._get("errors")


class _Keyboard:
    def __init__(self, page: FirefoxPage) -> None:
        self._page = page

    #: Playwright's key names that WebDriver BiDi (puppeteer) spells otherwise
    _KEYS = {"Space": " "}

    def _do(self, action: str, **args: Any) -> None:
        if "key" in args:
            args["key"] = self._KEYS.get(args["key"], args["key"])
        self._page._browser.call("keyboard", page=self._page._id, action=action, **args)

    def down(self, key: str) -> None:
        self._do("down", key=key)

    def up(self, key: str) -> None:
        self._do("up", key=key)

    def press(self, key: str) -> None:
        *mods, main = key.split("+") if len(key) > 1 else [key]
        for m in mods:
            self.down(m)
        self._do("press", key=main)
        for m in reversed(mods):
            self.up(m)

    def type(self, text: str) -> None:
        self._do("type", text=text)


class _Mouse:
    def __init__(self, page: FirefoxPage) -> None:
        self._page = page
        self._at = (0.0, 0.0)

    def _do(self, action: str, x: float = 0, y: float = 0) -> None:
        self._page._browser.call("mouse", page=self._page._id, action=action, x=x, y=y)

    def move(self, x: float, y: float, steps: int = 1) -> None:
        x0, y0 = self._at
        for i in range(1, steps + 1):
            self._do("move", x0 + (x - x0) * i / steps, y0 + (y - y0) * i / steps)
        self._at = (x, y)

    def down(self) -> None:
        self._do("down")

    def up(self) -> None:
        self._do("up")

    def click(self, x: float, y: float) -> None:
        self._do("click", x, y)
        self._at = (x, y)


class _Value:
    """What Playwright's ``expect_*`` context managers give: ``.value`` once the block has run."""

    def __init__(self) -> None:
        self.value: Any = None


class Download:
    def __init__(self, name: str, text: str) -> None:
        self.suggested_filename = name
        self._text = text

    def save_as(self, path: str | Path) -> None:
        Path(path).write_text(self._text)


class Response:
    def __init__(self, page: FirefoxPage, url: str) -> None:
        self._page = page
        self.url = url

    def json(self) -> Any:
        return self._page.evaluate("async (u) => (await fetch(u)).json()", self.url)

    def all_headers(self) -> dict[str, str]:
        """The headers of the same request made again in the page (names in lower case), its body not read."""
        return dict(
            self._page.evaluate(
                "async (u) => { const r = await fetch(u); const h = Object.fromEntries(r.headers);"
                " await r.body?.cancel(); return h; }",
                self.url,
            )
        )


class Handle:
    def __init__(self, value: Any) -> None:
        self._value = value

    def json_value(self) -> Any:
        return self._value


class Locator:
    def __init__(self, page: FirefoxPage, steps: list[list[Any]]) -> None:
        self._page = page
        self._steps = steps

    def __repr__(self) -> str:
        return f"Locator({self._steps})"

    # --- building
    def _with(self, *step: Any) -> Locator:
        return Locator(self._page, [*self._steps, list(step)])

    def locator(self, selector: str, has_text: str | None = None) -> Locator:
        loc = self._with("css", selector)
        return loc.filter(has_text=has_text) if has_text is not None else loc

    def get_by_test_id(self, test_id: str) -> Locator:
        return self._with("css", f'[data-testid="{test_id}"]')

    def get_by_role(self, role: str, name: str | None = None, exact: bool = False) -> Locator:
        return self._with("role", role, name, exact)

    def filter(self, has_text: str | None = None) -> Locator:
        return self._with("text", has_text) if has_text is not None else self

    def and_(self, other: Locator) -> Locator:
        return self._with("and", other._steps)

    def nth(self, index: int) -> Locator:
        return self._with("nth", index)

    @property
    def first(self) -> Locator:
        return self.nth(0)

    @property
    def last(self) -> Locator:
        return self.nth(-1)

    # --- reading (no waiting, as in Playwright)
    def _eval(self, fn: str, arg: Any = None) -> Any:
        return self._page.evaluate(
            f"([steps, arg]) => ({fn})(({_RESOLVE})(steps), arg)",
            [self._steps, arg],
        )

    def count(self) -> int:
        return int(self._eval("(els) => els.length"))

    def all_inner_texts(self) -> list[str]:
        return list(self._eval("(els) => els.map((e) => e.innerText)"))

    def is_visible(self) -> bool:
        return bool(
            self._one_or_none(
                "(e) => !!e && (() => { const r = e.getBoundingClientRect();"
                " return r.width > 0 && r.height > 0 &&"
                " getComputedStyle(e).visibility !== 'hidden'; })()"
            )
        )

    def is_hidden(self) -> bool:
        return not self.is_visible()

    def _one_or_none(self, fn: str) -> Any:
        out = self._eval(f"(els) => els.length > 1 ? {{many: els.length}} : {{v: ({fn})(els[0] ?? null) ?? null}}")
        if "many" in out:
            raise FirefoxError(f"strict mode: {self} matched {out['many']} elements")
        return out["v"]

    # --- reading one element (waits for it, strict)
    def _one(self, fn: str, arg: Any = None, timeout: float | None = None) -> Any:
        self.wait_for(state="attached", timeout=timeout)
        out = self._eval(
            f"(els, arg) => els.length === 1 ? {{v: ({fn})(els[0], arg) ?? null}} : {{n: els.length}}", arg
        )
        if "n" in out:
            raise FirefoxError(f"{self} matched {out['n']} elements")
        return out["v"]

    def inner_text(self, timeout: float | None = None) -> str:
        return str(self._one("(e) => e.innerText", timeout=timeout))

    def text_content(self, timeout: float | None = None) -> str:
        return str(self._one("(e) => e.textContent", timeout=timeout))

    def get_attribute(self, name: str, timeout: float | None = None) -> str | None:
        value = self._one("(e, n) => e.getAttribute(n)", name, timeout=timeout)
        return None if value is None else str(value)

    def is_disabled(self, timeout: float | None = None) -> bool:
        return bool(self._one("(e) => !!(e.disabled || e.closest('fieldset:disabled'))", timeout=timeout))

    def is_enabled(self, timeout: float | None = None) -> bool:
        return not self.is_disabled(timeout)

    def is_checked(self, timeout: float | None = None) -> bool:
        return bool(self._one("(e) => e.checked ?? e.getAttribute('aria-checked') === 'true'", timeout=timeout))

    def bounding_box(self, timeout: float | None = None) -> dict[str, float] | None:
        box = self._one(
            "(e) => { const r = e.getBoundingClientRect(); return r.width || r.height ?"
            " {x: r.x, y: r.y, width: r.width, height: r.height} : null; }",
            timeout=timeout,
        )
        return None if box is None else {k: float(v) for k, v in box.items()}

    def evaluate(self, expression: str, arg: Any = None) -> Any:
        return self._one(f"(e, arg) => ({expression})(e, arg)", arg)

    # --- waiting
    def wait_for(self, state: str = "visible", timeout: float | None = None) -> None:
        check = {
            "attached": "(els) => els.length > 0",
            "detached": "(els) => els.length === 0",
            "visible": "(els) => els.some((e) => { const r = e.getBoundingClientRect();"
            " return r.width > 0 && r.height > 0 && getComputedStyle(e).visibility !== 'hidden'; })",
            "hidden": "(els) => els.every((e) => { const r = e.getBoundingClientRect();"
            " return !(r.width > 0 && r.height > 0 && getComputedStyle(e).visibility !== 'hidden'); })",
        }[state]
        strict = json.dumps(state in ("attached", "visible"))
        fn = f"(els) => els.length > 1 && {strict} ? {{many: els.length}} : ({check})(els)"
        got = self._page._poll(
            lambda: self._eval(fn), timeout, f"{self} to be {state}", done=lambda v: v is True or isinstance(v, dict)
        )
        if isinstance(got, dict):
            raise FirefoxError(f"strict mode: {self} matched {got['many']} elements")

    # --- acting
    def _actionable(self, timeout: float | None, *, enabled: bool = True) -> dict[str, Any]:
        last: dict[str, Any] = {}

        def ready() -> dict[str, Any] | None:
            nonlocal last
            got = self._eval(_ACTIONABLE, [True, enabled])
            if got["count"] > 1:
                raise FirefoxError(f"strict mode: {self} matched {got['count']} elements")
            stable = got.get("box") is not None and got.get("box") == last.get("box")
            last = got
            return got if got["count"] == 1 and got.get("on") and stable else None

        try:
            return self._page._poll(ready, timeout, f"{self} to be actionable")  # type: ignore[no-any-return]
        except FirefoxError as exc:
            raise FirefoxError(f"{exc}; last seen {last}") from None

    def click(self, timeout: float | None = None) -> None:
        """Playwright's click: on an actionable element, and retried when the press lands on something else
        (the page moved between measuring and pressing: an alarm banner appeared above a robot row)."""
        deadline = time.monotonic() + (TIMEOUT_MS if timeout is None else timeout) / 1000
        while True:
            at = self._actionable(max(0.0, deadline - time.monotonic()) * 1000)
            self._eval(_GUARD_CLICK)
            self._page.mouse.click(at["x"], at["y"])
            verdict = self._page.evaluate(_GUARD_VERDICT)
            if verdict in (None, "hit"):
                return
            if time.monotonic() > deadline:
                raise FirefoxError(f"{self}: the click landed on {verdict}")

    def tap(self, timeout: float | None = None) -> None:
        """No touch in this Firefox: a mouse click (only pages made with ``touch_as_mouse`` get here)."""
        self.click(timeout)

    def hover(self, timeout: float | None = None) -> None:
        at = self._actionable(timeout, enabled=False)
        self._page.mouse.move(at["x"], at["y"])

    def check(self, timeout: float | None = None) -> None:
        if not self.is_checked(timeout):
            self.click(timeout)
        if not self.is_checked():
            raise FirefoxError(f"{self} did not become checked")

    def uncheck(self, timeout: float | None = None) -> None:
        if self.is_checked(timeout):
            self.click(timeout)

    def focus(self, timeout: float | None = None) -> None:
        self._one("(e) => e.focus()", timeout=timeout)

    def scroll_into_view_if_needed(self, timeout: float | None = None) -> None:
        self._one("(e) => e.scrollIntoView({block: 'center', inline: 'center'})", timeout=timeout)

    def fill(self, value: str, timeout: float | None = None) -> None:
        self._actionable(timeout)
        self._one(
            """(e, v) => { e.focus(); const proto = Object.getPrototypeOf(e);
              Object.getOwnPropertyDescriptor(proto, 'value').set.call(e, v);
              e.dispatchEvent(new InputEvent('input', {bubbles: true, composed: true}));
              e.dispatchEvent(new Event('change', {bubbles: true})); }""",
            value,
        )

    def select_option(self, value: str, timeout: float | None = None) -> None:
        self._actionable(timeout)
        ok = self._one(
            """(e, v) => { const o = [...e.options].find((o) => o.value === v || o.label === v);
              if (!o) return false; e.focus(); e.value = o.value;
              e.dispatchEvent(new Event('input', {bubbles: true}));
              e.dispatchEvent(new Event('change', {bubbles: true})); return true; }""",
            value,
        )
        if not ok:
            raise FirefoxError(f"{self} has no option {value!r}")

    def press(self, key: str, timeout: float | None = None) -> None:
        self.focus(timeout)
        self._page.keyboard.press(key)


class FirefoxPage:
    """A Firefox tab in its own browser context, with the Playwright calls the Chromium tests make."""

    def __init__(self, browser: FirefoxBrowser, page_id: int, base_url: str) -> None:
        self._browser = browser
        self._id = page_id
        self._base_url = base_url
        self.keyboard = _Keyboard(self)
        self.mouse = _Mouse(self)

    def _poll(
        self,
        probe: Callable[[], Any],
        timeout: float | None,
        what: str,
        done: Callable[[Any], bool] = bool,
    ) -> Any:
        deadline = time.monotonic() + (TIMEOUT_MS if timeout is None else timeout) / 1000
        last: Exception | None = None
        while True:
            try:
                value = probe()
                if done(value):
                    return value
            except FirefoxError as exc:
                if "strict mode" in str(exc):
                    raise
                last = exc  # e.g. the page navigated under the probe: try again
            if time.monotonic() > deadline:
                raise FirefoxError(f"timed out waiting for {what}; last error: {last}")
            time.sleep(POLL_S)

    # --- navigation
    def goto(self, url: str) -> None:
        self._browser.call("goto", page=self._id, url=urljoin(self._base_url, url))

    def reload(self) -> None:
        self._browser.call("reload", page=self._id)

    def go_back(self) -> None:
        self._browser.call("goBack", page=self._id)

    @property
    def url(self) -> str:
        return str(self._browser.call("url", page=self._id))

    def wait_for_url(self, url: str | re.Pattern[str] | Callable[[str], bool], timeout: float | None = None) -> None:
        if isinstance(url, str):
            pattern = re.escape(url).replace(r"\*\*", ".*").replace(r"\*", "[^/]*")
            matches: Callable[[str], bool] = lambda u: re.fullmatch(pattern, u) is not None  # noqa: E731
        elif isinstance(url, re.Pattern):
            matches = lambda u: url.search(u) is not None  # noqa: E731
        else:
            matches = url
        self._poll(lambda: matches(self.url), timeout, f"the URL {url}")

    def content(self) -> str:
        return str(self._browser.call("content", page=self._id))

    def close(self) -> None:
        self._browser.call("closePage", page=self._id)

    # --- script
    def evaluate(self, expression: str, arg: Any = None) -> Any:
        return self._browser.call("evaluate", page=self._id, expression=_call_expression(expression, arg))

    def wait_for_function(
        self, expression: str, arg: Any = None, timeout: float | None = None, polling: Any = None
    ) -> Handle:
        # a function is called with arg; its value counts when truthy in JavaScript
        probe = (
            f"async (arg) => {{ const f = ({expression}\n);"
            " const v = typeof f === 'function' ? await f(arg) : await f; return {ok: !!v, v}; }"
        )
        got = self._poll(lambda: self.evaluate(probe, arg), timeout, expression, done=lambda r: r["ok"])
        return Handle(got.get("v"))

    def wait_for_timeout(self, ms: float) -> None:
        time.sleep(ms / 1000)

    def screenshot(self, path: str | Path) -> None:
        """Saved, except into docs/screenshots: the documentation's pictures are Chromium's."""
        if SCREENSHOTS not in Path(path).resolve().parents:
            self._browser.call("screenshot", page=self._id, path=str(path))

    @property
    def context(self) -> _Context:
        return _Context(self)

    # --- locators
    def locator(self, selector: str, has_text: str | None = None) -> Locator:
        return Locator(self, []).locator(selector, has_text=has_text)

    def get_by_test_id(self, test_id: str) -> Locator:
        return Locator(self, []).get_by_test_id(test_id)

    def get_by_role(self, role: str, name: str | None = None, exact: bool = False) -> Locator:
        return Locator(self, []).get_by_role(role, name=name, exact=exact)

    def get_attribute(self, selector: str, name: str) -> str | None:
        return self.locator(selector).get_attribute(name)

    # --- expectations
    @contextlib.contextmanager
    def expect_download(self, timeout: float | None = None) -> Iterator[_Value]:
        """The file the page hands to an ``<a download>`` click: name and Blob text, read in the page. A
        ``blob:`` link's Blob is kept when the page makes its URL and read as it is: fetching that URL would
        be a connection the Content-Security-Policy refuses (``connect-src 'self'``), where the browser's
        own download of it is not one."""
        self.evaluate(
            """() => { window.__downloads = [];
              if (window.__captureDownloads) return;
              window.__captureDownloads = true;
              const blobs = new Map();
              const createObjectURL = URL.createObjectURL;
              URL.createObjectURL = function (obj) {
                const url = createObjectURL.call(URL, obj);
                if (obj instanceof Blob) blobs.set(url, obj);
                return url;
              };
              const click = HTMLAnchorElement.prototype.click;
              HTMLAnchorElement.prototype.click = function () {
                if (!this.hasAttribute('download')) return click.call(this);
                const entry = {name: this.download, text: null};
                window.__downloads.push(entry);
                const blob = blobs.get(this.href);
                (blob ? blob.text() : fetch(this.href).then((r) => r.text())).then((t) => { entry.text = t; });
              }; }"""
        )
        out = _Value()
        yield out
        got = self._poll(
            lambda: self.evaluate("() => window.__downloads.find((d) => d.text !== null) ?? null"),
            timeout,
            "a download",
        )
        out.value = Download(got["name"], got["text"])

    @contextlib.contextmanager
    def expect_request(self, predicate: Callable[[Any], bool], timeout: float | None = None) -> Iterator[_Value]:
        with self.expect_response(predicate, timeout) as out:
            yield out

    @contextlib.contextmanager
    def expect_response(self, predicate: Callable[[Any], bool], timeout: float | None = None) -> Iterator[_Value]:
        seen = len(FirefoxRecorder(self).requests)
        out = _Value()
        yield out

        def matching() -> str | None:
            for url in FirefoxRecorder(self).requests[seen:]:
                if predicate(Response(self, url)):
                    return url
            return None

        out.value = Response(self, self._poll(matching, timeout, "a matching response"))


class _Context:
    """A page's browser context (each Firefox page has its own)."""

    def __init__(self, page: FirefoxPage) -> None:
        self._page = page

    def cookies(self) -> list[dict[str, Any]]:
        return list(self._page._browser.call("cookies", page=self._page._id))

    def close(self) -> None:
        self._page.close()

    def new_page(self) -> FirefoxPage:
        return self._page


class _Browser:
    """Playwright's ``browser.new_context(...)`` for the tests that open their own contexts."""

    def __init__(self, pages: FirefoxPages) -> None:
        self._pages = pages

    def new_context(
        self, viewport: dict[str, int] | None = None, base_url: str = "", storage_state: Any = None
    ) -> _Context:
        size = viewport or {"width": 1280, "height": 720}
        cookies = (storage_state or {}).get("cookies", [])
        page = self._pages.open(size["width"], size["height"], cookies, base_url)
        return _Context(page)


class FirefoxPages:
    """``page_factory`` of the Chromium tests, for Firefox: pages on ``server``, closed by :meth:`close`."""

    def __init__(self, browser: FirefoxBrowser, server: Any, *, touch_as_mouse: bool = False) -> None:
        self._browser = browser
        self._server = server
        self._touch_as_mouse = touch_as_mouse
        self._pages: list[FirefoxPage] = []

    def __call__(
        self, width: int = 1280, height: int = 720, *, logged_in: bool = True, **options: Any
    ) -> tuple[FirefoxPage, FirefoxRecorder]:
        from tests.frontend.conftest import server_browser_auth

        touch = {k: options.pop(k) for k in ("has_touch", "is_mobile", "device_scale_factor") if k in options}
        if touch and not self._touch_as_mouse:
            raise FirefoxError(f"no touch emulation in this Firefox: {touch}")
        if options.pop("color_scheme", "light") != "light":
            raise FirefoxError("this Firefox runs in the light theme only (a browser-wide preference)")
        if options:
            raise FirefoxError(f"page options not supported in Firefox: {options}")
        auth = server_browser_auth(self._server) if logged_in else {}
        page = self.open(width, height, auth.get("storage_state", {}).get("cookies", []), self._server.base_url)
        return page, FirefoxRecorder(page)

    def open(self, width: int, height: int, cookies: list[dict[str, Any]], base_url: str) -> FirefoxPage:
        """A page in a new browser context holding ``cookies`` (Playwright's storage-state form)."""
        from tests.frontend.conftest import CSP_REPORTER

        cookies = [{k: v for k, v in c.items() if k != "expires" or v != -1} for c in cookies]
        page_id = self._browser.call("newPage", width=width, height=height, cookies=cookies, init=CSP_REPORTER)
        page = FirefoxPage(self._browser, page_id, base_url)
        self._pages.append(page)
        return page

    def as_browser(self) -> _Browser:
        """The Chromium tests' ``browser`` fixture, for those that make their own contexts."""
        return _Browser(self)

    def close(self) -> None:
        for page in self._pages:
            with contextlib.suppress(FirefoxError):
                page.close()
        self._pages.clear()
