"""Telemetry in: ingest into the store and the live hub, gap detection and repair, and the rollups."""
