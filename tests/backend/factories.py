"""Builds the command side of the server (relay, holds, e-stop, commands) the way the container does."""

from __future__ import annotations

from backend.comms.base import Publisher
from backend.services.access.audit import AuditService
from backend.services.control.commands import CommandService
from backend.services.control.leases import LeaseService
from backend.services.fleet.registry import Registry
from backend.services.legacy.relay import LegacyCommandRelay
from backend.services.live.hub import LiveHub
from backend.services.safety.estop import EStopService
from backend.services.safety.holds import HoldService
from backend.services.site.service import SiteService
from backend.store.writer import BatchWriter
from fleet_protocol import Topics, default_pool_site


def command_side(
    registry: Registry, publisher: Publisher, topics: Topics, writer: BatchWriter, hub: LiveHub
) -> tuple[CommandService, EStopService, HoldService, LegacyCommandRelay]:
    relay = LegacyCommandRelay(publisher=publisher, registry=registry)
    holds = HoldService(registry=registry, publisher=publisher, topics=topics, writer=writer)
    audit = AuditService(writer=writer)
    estop = EStopService(registry, publisher, topics, writer, hub, legacy=relay, audit=audit, signing_key=b"test")
    leases = LeaseService(writer=writer, hub=hub, registry=registry, audit=audit)
    site = SiteService(
        engine=writer._engine,
        publisher=publisher,
        topics=topics,
        audit=audit,
        default=default_pool_site(),
    )
    commands = CommandService(
        registry,
        publisher,
        topics,
        writer,
        hub,
        estop=estop,
        holds=holds,
        legacy=relay,
        leases=leases,
        audit=audit,
        site=site,
    )
    return commands, estop, holds, relay
