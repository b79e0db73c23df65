"""Driving a robot: commands and their tracking, control leases, and the WebSocket control sessions."""
