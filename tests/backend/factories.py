"""Builds the command side of the server (relay, holds, e-stop, commands) the way the container does."""

from __future__ import annotations

from backend.services.commands import CommandService
from backend.services.estop import EStopService
from backend.services.holds import HoldService
from backend.services.hub import LiveHub
from backend.services.leases import AuditService, LeaseService
from backend.services.legacy_commands import LegacyCommandRelay
from backend.services.publisher import Publisher
from backend.services.registry import Registry
from backend.services.site import SiteService
from backend.store.writer import BatchWriter
from fleet_protocol import Topics, default_pool_site


def command_side(
    registry: Registry, publisher: Publisher, topics: Topics, writer: BatchWriter, hub: LiveHub
) -> tuple[CommandService, EStopService, HoldService, LegacyCommandRelay]:
    relay = LegacyCommandRelay(publisher=publisher, registry=registry)
    holds = HoldService(registry=registry, publisher=publisher, topics=topics)
    estop = EStopService(registry, publisher, topics, writer, hub, legacy=relay)
    audit = AuditService(writer=writer)
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
