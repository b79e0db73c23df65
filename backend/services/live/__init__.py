"""Live views: the WebSocket hub that fans telemetry out to browsers, the camera relay, the Foxglove bridge."""
