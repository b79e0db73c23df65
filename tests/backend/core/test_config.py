"""Settings: env names, URL normalisation, redaction, production secrets."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from backend.core.config import Settings


def test_database_url_sources_and_normalisation(monkeypatch):
    for k in ("FLEET_DATABASE_URL", "DATABASE_URL"):
        monkeypatch.delenv(k, raising=False)
    assert Settings().database_url == "sqlite:///./data/fleet.db"
    monkeypatch.setenv("DATABASE_URL", "postgres://u:s3cret@db:5432/fleet")
    s = Settings()
    assert s.database_url == "postgresql+psycopg://u:s3cret@db:5432/fleet"
    assert "s3cret" not in s.database_url_redacted and "***" in s.database_url_redacted
    monkeypatch.setenv("FLEET_DATABASE_URL", "sqlite:////tmp/x.db")
    assert Settings().database_url == "sqlite:////tmp/x.db"  # the FLEET_ name wins


def test_production_requires_real_secrets(monkeypatch):
    monkeypatch.setenv("FLEET_ENVIRONMENT", "production")
    monkeypatch.delenv("FLEET_SECRET_KEY", raising=False)
    monkeypatch.delenv("FLEET_ADMIN_TOKEN", raising=False)
    with pytest.raises(ValidationError, match="FLEET_SECRET_KEY"):
        Settings()
    monkeypatch.setenv("FLEET_SECRET_KEY", "k" * 40)
    monkeypatch.setenv("FLEET_ADMIN_TOKEN", "changeme")
    with pytest.raises(ValidationError, match="FLEET_ADMIN_TOKEN"):
        Settings()
    monkeypatch.setenv("FLEET_ADMIN_TOKEN", "t" * 40)
    assert Settings().environment == "production"
    monkeypatch.setenv("FLEET_ENVIRONMENT", "development")
    monkeypatch.setenv("FLEET_ADMIN_TOKEN", "")
    assert Settings().admin_token.get_secret_value() == ""  # development does not care
