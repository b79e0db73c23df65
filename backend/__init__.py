"""Mollusca Fleet server: MQTT bridge, telemetry store, REST + WebSocket API and the dashboard."""

__version__ = "0.1.0"
