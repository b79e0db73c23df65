"""Mollusca Fleet robot agent: runs on each robot (or simulated), speaks the fleet MQTT protocol."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("mollusca-fleet")
except PackageNotFoundError:  # running from a source tree without install
    __version__ = "0.0.0+src"
