"""Telemetry in: ingest into the store and the live hub, gap detection and repair, and the rollups; and
out: the readers (history reads and exports on a pool of their own, admitted and bounded)."""
