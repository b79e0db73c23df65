# The base-station image: `fleet-server` (default command) and `fleet-agent` (the compose `sim` robots and
# the discovery beacon run it from the same image). Installs the package the tests install,
# `pip install '.[server]'` from this repository; simulated robots need nothing more (no vision extra).
# The compose `broker-init` service (as Mosquitto's uid 1883) writes the broker's passwd + acl from it too.
# Build: docker compose build (or docker build -t mollusca-fleet .). Checked by tests/deploy/test_compose.py.
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1 \
    VIRTUAL_ENV=/opt/venv PATH=/opt/venv/bin:$PATH

RUN python -m venv /opt/venv \
    && useradd --system --create-home --uid 10001 --user-group fleet \
    && mkdir -p /data /mosquitto/auth && chown fleet:fleet /data \
    && chown 1883:1883 /mosquitto/auth

WORKDIR /app
COPY pyproject.toml README.md ./
COPY fleet_protocol ./fleet_protocol
COPY fleet_common ./fleet_common
COPY robot_agent ./robot_agent
COPY backend ./backend
COPY fleet_client ./fleet_client
COPY frontend ./frontend
COPY deploy/mosquitto/acl.example ./deploy/mosquitto/acl.example
RUN pip install '.[server]' && rm -rf build *.egg-info

USER fleet
VOLUME ["/data"]
ENV FLEET_DATABASE_URL=sqlite:////data/fleet.db FLEET_FRONTEND_DIR=/app/frontend
EXPOSE 8000
HEALTHCHECK --interval=15s --timeout=5s --start-period=30s --retries=3 \
    CMD ["python", "-c", "import json, sys, urllib.request; r = urllib.request.urlopen('http://127.0.0.1:8000/api/health', timeout=4); sys.exit(0 if json.load(r)['status'] == 'ok' else 1)"]
CMD ["fleet-server", "serve", "--host", "0.0.0.0", "--port", "8000"]
