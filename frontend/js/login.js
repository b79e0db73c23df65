// The login page: POST /api/auth/login sets the HttpOnly session cookie, then back to ?next= (a path on
// this site only: never an open redirect).

function nextPath() {
  const next = new URLSearchParams(location.search).get("next") ?? "/";
  // A path on this site only. URL parsers drop tabs and newlines ("/\t/evil.example" is "//evil.example")
  // and read "\" as "/": refuse control characters and backslashes outright, then normalise and check that
  // the result is still this origin.
  if (/[\u0000-\u001f\u007f\\]/.test(next) || !next.startsWith("/") || next.startsWith("//")) return "/";
  let url;
  try {
    url = new URL(next, location.origin);
  } catch {
    return "/";
  }
  if (url.origin !== location.origin || url.pathname.startsWith("/login")) return "/";
  return url.pathname + url.search + url.hash;
}

async function alreadyLoggedIn() {
  try {
    const res = await fetch("/api/auth/me", { credentials: "same-origin" });
    return res.ok;
  } catch {
    return false;
  }
}

function setup() {
  const form = document.getElementById("login-form");
  const user = document.getElementById("login-username");
  const pass = document.getElementById("login-password");
  const error = document.getElementById("login-error");
  const submit = form.querySelector("button[type=submit]");
  user.focus();
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    error.textContent = "";
    if (!user.value || !pass.value) {
      error.textContent = "Enter your username and password.";
      return;
    }
    submit.disabled = true;
    try {
      const res = await fetch("/api/auth/login", {
        method: "POST",
        credentials: "same-origin",
        headers: { "Content-Type": "application/json" },
        body: JSON.stringify({ username: user.value.trim(), password: pass.value }),
      });
      if (res.ok) {
        location.replace(nextPath());
        return;
      }
      if (res.status === 429) {
        const wait = res.headers.get("Retry-After");
        error.textContent = `Too many attempts: try again${wait ? ` in ${wait} s` : " later"}.`;
      } else if (res.status === 401 || res.status === 422) {
        error.textContent = "Wrong username or password.";
      } else {
        error.textContent = `Login failed (HTTP ${res.status}).`;
      }
      pass.select();
    } catch {
      error.textContent = "The server cannot be reached.";
    } finally {
      submit.disabled = false;
    }
  });
  alreadyLoggedIn().then((yes) => yes && location.replace(nextPath()));
}

setup();
