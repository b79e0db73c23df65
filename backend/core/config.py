"""Server settings: one pydantic-settings class, environment prefix ``FLEET_``."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal
from urllib.parse import urlsplit, urlunsplit

from pydantic import AliasChoices, Field, SecretStr, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict
from sqlalchemy.engine import make_url

from fleet_protocol.motion import SiteTag

REPO_ROOT = Path(__file__).resolve().parents[2]

#: Values that must never reach production as secrets.
PLACEHOLDER_SECRETS = frozenset({"", "changeme", "change-me", "changethis", "secret", "password", "admin", "default"})


#: Production secrets shorter than this are refused.
MIN_SECRET_LENGTH = 32


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="FLEET_", populate_by_name=True, extra="ignore")

    environment: Literal["development", "production"] = Field(
        default="development",
        validation_alias=AliasChoices("FLEET_ENV", "FLEET_ENVIRONMENT", "environment"),
    )
    log_level: str = "INFO"
    #: "json": one JSON object per line with robot_id/command_id fields (for log shippers)
    log_format: Literal["text", "json"] = "text"

    mqtt_url: str = "mqtt://127.0.0.1:1883"
    #: Broker credentials kept apart from the URL (compose passes FLEET_MQTT_PASSWORD from .env); when set
    #: they win over any user:password in ``mqtt_url``. The user name defaults to the ACL's server account.
    mqtt_username: str = "fleet-server"
    mqtt_password: SecretStr = SecretStr("")
    #: The server's MQTT name: its client id is ``<name>-<secret suffix>`` (the suffix kept in ``data_dir``,
    #: backend/comms/client_id.py), the same on every restart, so the broker keeps its session (subscriptions
    #: + queued QoS 1 messages). Empty: "fleet-server-<hostname>". Every replica needs its own name or data_dir.
    mqtt_client_id: str = ""
    #: The server's own files (the client id's secret suffix); none: the SQLite file's directory, else ./data
    data_dir: Path | None = None
    mqtt_keepalive_s: int = Field(default=10, ge=2, le=600)
    #: "5" (MQTT v5: shared subscriptions, session expiry) or "3.1.1" (brokers without v5, e.g. amqtt).
    mqtt_protocol: Literal["5", "3.1.1"] = "5"
    #: How long the broker keeps the server's session (and queues for it) while it is away.
    mqtt_session_expiry_s: int = Field(default=86400, ge=0)
    #: QoS 1 messages the broker may have in flight to the server before PUBACKs (acks follow DB commits).
    #: A full window stops the broker sending, live data included: 10,000 holds 2.5 s of a 200-robot fleet
    #: at 20 Hz (the slowest SQLite commit seen under that load took 1.3 s); paho's packet ids cap it at 65,535.
    mqtt_receive_maximum: int = Field(default=10000, ge=10, le=65535)
    #: Replicas: telemetry is stored via the shared subscription $share/<group>/... (once per message);
    #: every replica still subscribes non-shared to status, acks, e-stop and live telemetry.
    ingest_shared_group: str = Field(default="", pattern=r"^[A-Za-z0-9_-]*$", max_length=64)
    topic_prefix: str = "fleet"
    legacy_enabled: bool = True

    database_url: str = Field(
        default="sqlite:///./data/fleet.db",
        validation_alias=AliasChoices("FLEET_DATABASE_URL", "DATABASE_URL", "database_url"),
    )
    frontend_dir: Path = REPO_ROOT / "frontend"
    #: SQLite durability: NORMAL (WAL: a server crash loses nothing; a power cut may lose the last commits)
    #: or FULL (fsync per commit: survives power cuts, slower ingest)
    sqlite_synchronous: Literal["NORMAL", "FULL"] = "NORMAL"

    # Ingest tuning.
    writer_batch_rows: int = Field(default=1000, ge=1)
    writer_batch_interval_s: float = Field(default=0.1, gt=0)
    writer_queue_max: int = Field(default=100_000, ge=100)
    #: writes (audit, commands, events) kept for a retry while the database is away; beyond, given up (counted,
    #: alarmed: store_writes_lost) and the ack of the message that caused it withheld (store/write_retry.py)
    writer_retry_max: int = Field(default=10_000, ge=1)
    #: an event-loop stall this long raises the fleet-wide ``loop_stall`` alarm (core/loopwatch.py)
    loop_stall_alarm_s: float = Field(default=0.2, gt=0, le=60)
    #: the server warns when its own fleet poses do not come back this soon after connecting: the broker's ACL
    #: refuses them (services/fleet/poses.py)
    poses_acl_check_s: float = Field(default=5.0, gt=0, le=600)
    inbound_queue_max: int = Field(default=200_000, ge=100)
    #: Parse plain PUBLISH packets straight from the read buffer (backend/comms/fast_path.py); it still
    #: turns itself off, saying so in the log and /api/stats, on a paho release other than the tested one.
    mqtt_fast_path: bool = True

    # Rollup and retention (backend/services/telemetry/rollups.py runs store/rollup.py and store/retention.py):
    # raw telemetry is rolled up into per-second and per-minute aggregates; raw rows older than raw_days are
    # deleted (their aggregates stay), aggregates older than agg_days are pruned. 0 keeps forever.
    retention_raw_days: float = Field(default=30.0, ge=0)
    retention_agg_days: float = Field(default=365.0, ge=0)
    retention_interval_s: float = Field(default=3600.0, gt=0)
    #: the audit trail (who did what) is kept this long, whatever telemetry retention does (0: forever);
    #: the same retention pass prunes it
    retention_audit_days: float = Field(default=365.0, ge=0)
    #: how often the minutes with new raw rows are rolled up into the aggregates (long-range queries)
    rollup_interval_s: float = Field(default=5.0, gt=0)
    # History queries: raw exports (csv/ndjson without a limit) larger than this are refused with 422; it is
    # also the largest ``limit`` (rows per export page) a raw export accepts.
    history_export_max_rows: int = Field(default=1_000_000, ge=1)
    # Readers (docs/server.md "Readers and exports"): history reads and exports use a database pool of their
    # own, so they can never take the connections of the writer, leases, audit or health.
    #: connections of the readers' pool (no overflow); history reads beyond it queue for one
    reader_pool_size: int = Field(default=4, ge=1, le=64)
    #: a reader's statement is cancelled after this long (PostgreSQL statement_timeout; SQLite: interrupted);
    #: 0: no limit
    reader_statement_timeout_s: float = Field(default=30.0, ge=0)
    #: PostgreSQL: a reader's transaction left idle this long is ended (idle_in_transaction_session_timeout)
    reader_idle_timeout_s: float = Field(default=60.0, ge=1)
    #: exports (CSV/NDJSON history, run MCAP/Parquet/zip) running at once, in all and per client (a user from
    #: one address); the next gets 503 / 429 with Retry-After. Also the size of the exports' thread pool.
    export_max_concurrent: int = Field(default=8, ge=1, le=256)
    export_max_per_client: int = Field(default=2, ge=1, le=256)
    #: the Retry-After of a refused export, seconds
    export_retry_after_s: int = Field(default=5, ge=1, le=3600)
    #: a download that accepts no data for this long is cut off, freeing its slot
    export_stall_timeout_s: float = Field(default=30.0, gt=0, le=3600)
    #: a run's Parquet file gets a column for at most this many distinct data keys per stream (first seen
    #: first); the rest of a row's keys go, as one JSON object, in its ``other_fields`` column
    export_parquet_max_fields: int = Field(default=256, ge=1, le=10_000)
    #: Experiment runs (docs/runs.md): camera frames are kept as JPEG files under ``runs_dir/<run id>/``;
    #: when the store would grow past ``runs_frames_quota_mb`` a run stops keeping frames (telemetry goes on).
    #: none: ``runs/`` beside a SQLite database file, else ./data/runs (see ``frames_root``)
    runs_dir: Path | None = None
    runs_frames_quota_mb: float = Field(default=2048.0, ge=0)
    #: Live to Foxglove / Lichtblick (docs/runs.md): a read-only Foxglove WebSocket server (foxglove-sdk, the
    #: ``foxglove`` extra) with every robot's pose, camera and detections; off by default. It has no
    #: authentication of its own: keep it on 127.0.0.1 and reach it through an SSH tunnel, or an
    #: authenticating proxy, when the fleet's authentication is on.
    foxglove_ws: bool = False
    foxglove_ws_host: str = Field(default="127.0.0.1", min_length=1, max_length=255)
    foxglove_ws_port: int = Field(default=8765, ge=0, le=65535)
    #: How long an idle HTTP keep-alive connection stays open. Longer than a client's own expiry (httpx: 5 s),
    #: so that a script that pauses between calls never sends on a connection the server is just closing
    #: ("Server disconnected without sending a response", seen at uvicorn's default of exactly 5 s).
    http_keepalive_s: int = Field(default=30, ge=1, le=3600)

    # Site (``GET /api/site``): the pool outline in the Lighthouse frame, metres, as a JSON list of [x, y]
    # corners (FLEET_POOL_BOUNDARY='[[-3,-2],[3,-2],[3,2],[-3,2]]'). Default: the simulator's 4 m x 4 m pool.
    pool_boundary: list[tuple[float, float]] = Field(
        default_factory=lambda: [(-2.0, -2.0), (2.0, -2.0), (2.0, 2.0), (-2.0, 2.0)], min_length=3, max_length=1000
    )
    #: The site's AprilTag map (wall tags: id, size_m, pose x/y/z/yaw with yaw the way the printed face looks),
    #: as a JSON list (FLEET_SITE_TAGS='[{"id": 0, "size_m": 0.1, "pose": {"x": 2, "y": 0, "z": 0.1,
    #: "yaw": 3.14159}}]'): with FLEET_POOL_BOUNDARY it seeds the site's first version (later versions come
    #: from PUT /api/site); the ``localization_disagreement`` alarm checks the Lighthouse against the current
    #: site's tags. Empty: no check.
    site_tags: list[SiteTag] = Field(default_factory=list, max_length=1000)

    #: Control lease: it lapses this long after its holder's last drive (a goal under way keeps it).
    lease_lapse_s: float = Field(default=60.0, ge=1.0, le=3600.0)

    # Registry.
    stale_after_s: float = 2.0
    legacy_offline_after_s: float = 10.0
    command_ack_timeout_grace_s: float = 3.0

    # Live hub.
    ws_client_queue_max: int = Field(default=2000, ge=10)
    #: a client gets at most one frame per interval: batching vs latency (5 ms keeps p50 latency low)
    ws_flush_interval_s: float = Field(default=0.005, gt=0, le=0.05)

    # Authentication (issue 6, docs/security.md).
    #: FLEET_AUTH=off: no authentication at all, everyone is admin. Demo only: logged loudly, refused in
    #: production.
    auth: bool = True
    #: HMAC key for session ids (changing it logs every browser out). Production: >= 32 characters.
    secret_key: SecretStr = SecretStr("")
    #: An admin bearer token from the environment (the first admin). Production: >= 32 characters.
    admin_token: SecretStr = SecretStr("")
    #: Extra browser Origins allowed for WebSocket and cookie-authenticated writes, comma-separated
    #: (e.g. "https://fleet.lab.example"); the server's own host is always allowed.
    allowed_origins: str = ""
    #: Host names this server answers to besides localhost, its own names and any IP address, comma-separated
    #: (e.g. "fleet.lab.example,.lab.example"; "*": any). Any other Host gets 400, auth on or off: a page
    #: on another site cannot reach the server through DNS rebinding.
    allowed_hosts: str = ""
    session_ttl_s: float = Field(default=12 * 3600, ge=60)
    #: API tokens expire this many days after they are made (the default and the most ``expires_in_s`` may
    #: ask for: no token lives forever); tokens older than the setting are cut to it at start.
    token_ttl_days: float = Field(default=90.0, gt=0, le=3650)
    #: Mark the session cookie Secure even on plain-HTTP requests (set it when TLS ends at a proxy).
    cookie_secure: bool = False
    #: Commands per user and robot: a token bucket of this rate and burst; excess gets 429. (The
    #: dashboard's hold-to-drive resends every 100 ms: 10/s, half of this.)
    command_rate_per_s: float = Field(default=20.0, gt=0)
    command_burst: int = Field(default=40, ge=1)
    #: Failed logins per username and client address: 5 in a row, then one per 2 s.
    login_rate_per_s: float = Field(default=0.5, gt=0)
    login_burst: int = Field(default=5, ge=1)
    #: Logins per client address whatever the username (10, then one per 5 s), and from everyone together
    #: (60, then 5 per s): beyond either, 429 before any password is checked.
    login_address_rate_per_s: float = Field(default=0.2, gt=0)
    login_address_burst: int = Field(default=10, ge=1)
    login_total_rate_per_s: float = Field(default=5.0, gt=0)
    login_total_burst: int = Field(default=60, ge=1)
    #: Request bodies over this size get 413.
    max_body_bytes: int = Field(default=64 * 1024, ge=1024)
    #: Mosquitto password file that `fleet-server robots add` / `broker-user` write.
    mqtt_password_file: Path = REPO_ROOT / "deploy" / "mosquitto" / "passwd"

    @field_validator("database_url")
    @classmethod
    def _normalise_db_url(cls, v: str) -> str:
        """Plain ``postgres://``/``postgresql://`` URLs (as DATABASE_URL usually is) use psycopg 3."""
        if v.startswith("postgres://"):
            v = "postgresql://" + v[len("postgres://") :]
        if v.startswith("postgresql://"):
            v = "postgresql+psycopg://" + v[len("postgresql://") :]
        return v

    @field_validator("pool_boundary")
    @classmethod
    def _finite_boundary(cls, v: list[tuple[float, float]]) -> list[tuple[float, float]]:
        if not all(math.isfinite(c) for corner in v for c in corner):
            raise ValueError("pool_boundary: every corner is two finite numbers [x, y] in metres")
        return v

    @model_validator(mode="after")
    def _production_secrets(self) -> Settings:
        if self.environment == "production":
            for name in ("secret_key", "admin_token"):
                value: SecretStr = getattr(self, name)
                if value.get_secret_value().strip().lower() in PLACEHOLDER_SECRETS:
                    raise ValueError(f"FLEET_{name.upper()} must be set to a real secret in production")
                if len(value.get_secret_value()) < MIN_SECRET_LENGTH:
                    raise ValueError(
                        f"FLEET_{name.upper()} is too short for production (at least {MIN_SECRET_LENGTH} "
                        "characters; e.g. `python -c 'import secrets; print(secrets.token_urlsafe(32))'`)"
                    )
            if not self.auth:
                raise ValueError("FLEET_AUTH=off is for the demo only and refused in production")
        return self

    @property
    def database_url_redacted(self) -> str:
        return make_url(self.database_url).render_as_string(hide_password=True)

    @property
    def mqtt_credentials(self) -> tuple[str, str] | None:
        """(username, password) from FLEET_MQTT_USERNAME/FLEET_MQTT_PASSWORD, or None (use the URL's)."""
        password = self.mqtt_password.get_secret_value()
        return (self.mqtt_username, password) if password else None

    @property
    def mqtt_url_redacted(self) -> str:
        """The broker URL without its password (``mqtt://user:***@host:port``)."""
        parts = urlsplit(self.mqtt_url)
        if parts.password is None:
            return self.mqtt_url
        netloc = f"{parts.username or ''}:***@{parts.hostname or ''}" + (f":{parts.port}" if parts.port else "")
        return urlunsplit(parts._replace(netloc=netloc))

    @property
    def allowed_origin_set(self) -> frozenset[str]:
        return frozenset(o.strip().rstrip("/").lower() for o in self.allowed_origins.split(",") if o.strip())

    @property
    def server_data_dir(self) -> Path:
        """``data_dir``, or the directory of the SQLite file (a Docker volume keeps both), else ./data."""
        if self.data_dir is not None:
            return self.data_dir
        url = make_url(self.database_url)
        if url.get_backend_name() == "sqlite" and url.database and url.database != ":memory:":
            return Path(url.database).parent
        return Path("./data")

    @property
    def frames_root(self) -> Path:
        """Where runs keep their camera frames: ``runs_dir``, or beside the SQLite file it goes with."""
        if self.runs_dir is not None:
            return self.runs_dir
        url = make_url(self.database_url)
        if url.get_backend_name() == "sqlite" and url.database and url.database != ":memory:":
            return Path(url.database).parent / "runs"
        return Path("./data/runs")
