#!/usr/bin/env bash
# Installs the Debian packages the test suite and the demo need, only those that are missing (idempotent;
# `apt-get update` runs only when something is missing):
#   mosquitto          the MQTT broker the tests start on free ports (and `make demo` uses when present);
#                      also brings mosquitto_passwd, which the ACL test uses
#   mosquitto-clients  mosquitto_sub / mosquitto_pub, for looking at the wire (docs/troubleshooting.md)
#   chromium           the browser Playwright drives in the dashboard tests (Debian's build: no download)
#   firefox-esr        the second browser (tests/frontend/test_firefox.py, over WebDriver BiDi)
#   nodejs, npm        only when there is no node/npm: they run that Firefox test (puppeteer-core)
#   fonts-liberation, fonts-dejavu-core   fonts for the dashboard screenshots
#   docker-compose     Debian's Compose v1, used only to validate docker-compose.yml in the tests
#   openssl            makes a private CA and a broker certificate for the TLS test of the server's bridge
#   python3-venv       when there is no python3.11 with venv support
# Runs as root (CI) or through sudo. Usage: scripts/ensure-system-deps.sh [--check]  (--check: only report)
set -euo pipefail

installed() { dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q "install ok installed"; }

need=()
for pkg in mosquitto mosquitto-clients chromium firefox-esr fonts-liberation fonts-dejavu-core docker-compose openssl; do
  installed "$pkg" || need+=("$pkg")
done
if ! command -v node >/dev/null 2>&1 || ! command -v npm >/dev/null 2>&1; then
  need+=(nodejs npm)
fi
# Python 3.11 with venv (Makefile: python3.11, else python3)
py=$(command -v python3.11 || command -v python3 || true)
if [ -z "$py" ] || ! "$py" -c 'import ensurepip, venv' >/dev/null 2>&1; then
  need+=(python3 python3-venv)
fi

if [ ${#need[@]} -eq 0 ]; then
  exit 0
fi
if [ "${1:-}" = "--check" ]; then
  echo "ensure-system-deps: missing: ${need[*]}"
  exit 1
fi

SUDO=()
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then
    SUDO=(sudo)
  else
    echo "ensure-system-deps: need root (or sudo) to install: ${need[*]}" >&2
    exit 1
  fi
fi

echo "ensure-system-deps: installing ${need[*]}"
"${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive apt-get update -qq
"${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
# Debian's mosquitto package may start a system broker on 1883; nothing here relies on it (the tests pick
# free ports, `make demo` takes another port when 1883 is busy).
echo "ensure-system-deps: done"
