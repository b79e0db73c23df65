"""Small helpers the robot agent and the server share (no paho, no FastAPI, no SQLAlchemy): one backoff
and one rate-limited logger, so a retry or a flood of bad input behaves the same on both sides."""

from fleet_common.backoff import Backoff
from fleet_common.ratelimit import RateLimitedLogger

__all__ = ["Backoff", "RateLimitedLogger"]
