#!/usr/bin/env bash
# Install the Mollusca Fleet agent on Raspberry Pi OS (Bookworm, Pi 5). Idempotent: run again to upgrade.
#   sudo ./robot_agent/deploy/install-pi.sh [ROBOT_ID]
#   sudo ./robot_agent/deploy/install-pi.sh --enrol SERVER TOKEN [--cacert FILE]
# --enrol: the line `fleet-server robots add ID` prints on the base station. The single-use token is
# exchanged for the robot's id, broker password and the base station's fleet key, written into agent.toml
# (mode 0600): no password is ever typed or shown (docs/security.md, "Discovery and enrolment").
set -euo pipefail

REPO="$(cd "$(dirname "$0")/../.." && pwd)"
PREFIX=/opt/fleet-agent
CONF_DIR=/etc/fleet-agent
ENROL_SERVER=""
ENROL_TOKEN=""
ENROL_CACERT=""
ROBOT_ID="$(hostname -s)"
while [ $# -gt 0 ]; do
  case "$1" in
    --enrol)
      [ $# -ge 3 ] || { echo "usage: $0 --enrol SERVER TOKEN [--cacert FILE]" >&2; exit 2; }
      ENROL_SERVER="$2"; ENROL_TOKEN="$3"; shift 3 ;;
    --cacert)
      [ $# -ge 2 ] || { echo "--cacert needs a file" >&2; exit 2; }
      ENROL_CACERT="$2"; shift 2 ;;
    -*) echo "unknown option $1 (usage: $0 [ROBOT_ID] | --enrol SERVER TOKEN [--cacert FILE])" >&2; exit 2 ;;
    *) ROBOT_ID="$1"; shift ;;
  esac
done

if [ "$(id -u)" -ne 0 ]; then
  echo "run as root (sudo)" >&2
  exit 1
fi

apt-get update -qq
# picamera2 and libcamera come from Raspberry Pi OS, not PyPI: the venv sees them (--system-site-packages)
DEBIAN_FRONTEND=noninteractive apt-get install -y -qq python3-venv python3-picamera2 python3-lgpio >/dev/null

id fleet >/dev/null 2>&1 || useradd --system --home "$PREFIX" --shell /usr/sbin/nologin fleet
usermod -a -G gpio,video fleet || true

install -d "$PREFIX" "$CONF_DIR"
if [ ! -x "$PREFIX/.venv/bin/python" ]; then
  python3 -m venv --system-site-packages "$PREFIX/.venv"
fi
"$PREFIX/.venv/bin/pip" install -q --upgrade pip
# picamera2's compiled helpers (simplejpeg) are built against the system numpy: the venv must keep the same
# numpy major version, or importing picamera2 fails ("numpy.dtype size changed"). Bookworm ships numpy 1.x,
# and opencv-python-headless >= 4.12 requires numpy 2.
CONSTRAINTS="$PREFIX/constraints.txt"
SYS_NUMPY_MAJOR="$(/usr/bin/python3 -c 'import numpy; print(numpy.__version__.split(".")[0])' 2>/dev/null || true)"
if [ "$SYS_NUMPY_MAJOR" = "1" ]; then
  printf 'numpy<2\nopencv-python-headless<4.12\n' > "$CONSTRAINTS"
else
  : > "$CONSTRAINTS"
fi
"$PREFIX/.venv/bin/pip" install -q --constraint "$CONSTRAINTS" "$REPO[vision,pi]"
ln -sf "$PREFIX/.venv/bin/fleet-agent" /usr/local/bin/fleet-agent   # fleet-agent discover/detect/calibrate

if [ ! -f "$CONF_DIR/agent.toml" ]; then
  sed "s/^robot_id = .*/robot_id = \"$ROBOT_ID\"/" "$REPO/robot_agent/deploy/agent.example.toml" > "$CONF_DIR/agent.toml"
  chmod 600 "$CONF_DIR/agent.toml"   # it will hold the robot's broker password
  echo "wrote $CONF_DIR/agent.toml (robot_id = $ROBOT_ID): check the motor pins and camera settings"
fi
if [ -n "$ENROL_SERVER" ]; then
  # the token expires (30 minutes by default) and works once: a failure here needs a new `robots add` line
  "$PREFIX/.venv/bin/fleet-agent" enrol "$ENROL_SERVER" "$ENROL_TOKEN" --config "$CONF_DIR/agent.toml" \
    ${ENROL_CACERT:+--cacert "$ENROL_CACERT"}
fi
chown -R fleet:fleet "$CONF_DIR"

install -m 644 "$REPO/robot_agent/deploy/fleet-agent.service" /etc/systemd/system/fleet-agent.service
systemctl daemon-reload
systemctl enable --now fleet-agent
systemctl --no-pager status fleet-agent | head -5
echo "done: journalctl -u fleet-agent -f"
