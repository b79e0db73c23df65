"""What services need from the broker link (a protocol: services never see the MQTT client library)."""

from __future__ import annotations

from typing import Protocol


class Publisher(Protocol):
    @property
    def connected(self) -> bool: ...

    def publish(self, topic: str, payload: bytes | str, qos: int = 1, retain: bool = False) -> bool: ...
