"""The site: one model of the pool (boundary, keep-outs, base stations, wall tags), versioned in the
database and published retained on ``{prefix}/site`` so that every robot (and one that starts later) has it.

- The database is the truth, shared by replicas: reads of the current site (``GET /api/site``, the goal
  check) take the newest row. Every change appends a version with who and when, and is audited.
- On the first start (no version yet) version 1 comes from ``FLEET_POOL_BOUNDARY``.
- "No site" (``DELETE /api/site``) is a version too, published as ``{"site": null}``: robots then know there
  is no fence, as opposed to not having heard the topic yet (they refuse goals until they have).
- Published at each (re)connection to the broker (after reading the newest version) and after each change.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from dataclasses import dataclass, field
from typing import Any

from pydantic import ValidationError
from sqlalchemy import Engine

from backend.comms.base import Publisher
from backend.core.errors import ServiceError, format_errors
from backend.services.access.audit import Actor, AuditService
from backend.services.site.geofence import ServerFence, SiteRefused, check_site
from backend.store import site as store
from fleet_protocol import QOS_SITE, AvoidanceSettings, Site, SiteMessage, Topics, dumps
from fleet_protocol.motion import SiteTag

log = logging.getLogger(__name__)

GOAL_COMMANDS = frozenset({"goto", "follow_path"})


@dataclass(frozen=True)
class SiteVersion:
    version: int
    site: Site | None
    source: str
    updated_by: str
    updated_at: float
    #: the robots' safety filter (a version stored before it had none: the defaults)
    avoidance: AvoidanceSettings = field(default_factory=AvoidanceSettings)

    @classmethod
    def from_row(cls, row: dict[str, Any]) -> SiteVersion:
        site = None if row["site"] is None else Site.model_validate(row["site"])
        stored = row.get("avoidance")
        avoidance = AvoidanceSettings() if stored is None else AvoidanceSettings.model_validate(stored)
        return cls(row["version"], site, row["source"], row["updated_by"], row["updated_at"], avoidance)

    def message(self) -> SiteMessage:
        """With the avoidance settings even for "no site": robots keep apart without a fence too."""
        return SiteMessage(version=self.version, site=self.site, ts=self.updated_at, avoidance=self.avoidance)


class SiteService:
    def __init__(
        self,
        *,
        engine: Engine,
        publisher: Publisher,
        topics: Topics,
        audit: AuditService,
        default: Site,
    ) -> None:
        self._engine = engine
        self._publisher = publisher
        self._topic = topics.site()
        self._audit = audit
        self._default = default
        self.current: SiteVersion | None = None
        self._fence: tuple[int, ServerFence | None] | None = None
        self._republish: asyncio.Task[None] | None = None
        self.published = 0

    # -- reading -------------------------------------------------------------------------------------------
    async def load(self) -> SiteVersion:
        """The newest version; on the very first start, version 1 from the setting."""
        row = await asyncio.to_thread(store.latest_site, self._engine)
        if row is None:
            seed = self._default.model_dump(mode="json")
            avoidance = AvoidanceSettings().model_dump(mode="json")
            with contextlib.suppress(store.SiteConflict):  # another replica seeded it first: take theirs
                await asyncio.to_thread(
                    store.append_site,
                    self._engine,
                    seed,
                    "setting",
                    "FLEET_POOL_BOUNDARY",
                    time.time(),
                    True,
                    avoidance,
                )
            row = await asyncio.to_thread(store.latest_site, self._engine)
            assert row is not None
            log.info("site version %d seeded from FLEET_POOL_BOUNDARY", row["version"])
        return self._adopt(SiteVersion.from_row(row))

    def _adopt(self, version: SiteVersion) -> SiteVersion:
        if self.current is None or version.version >= self.current.version:
            self.current = version
        return self.current

    async def latest(self) -> SiteVersion:
        """The current version as the database has it (another replica may have changed it)."""
        row = await asyncio.to_thread(store.latest_site, self._engine)
        if row is None:
            return await self.load()
        return self._adopt(SiteVersion.from_row(row))

    async def versions(self, limit: int, before: int | None) -> list[SiteVersion]:
        rows = await asyncio.to_thread(store.list_site_versions, self._engine, limit, before)
        return [SiteVersion.from_row(r) for r in rows]

    # -- changing ------------------------------------------------------------------------------------------
    async def at(self, version: int) -> SiteVersion:
        """That version of the site (what a run or a goal was checked against); the current one if it is gone."""
        found = await self.versions(1, version + 1)
        return found[0] if found and found[0].version == version else await self.latest()

    async def replace(
        self, site: dict[str, Any] | None, actor: Actor, avoidance: dict[str, Any] | None = None
    ) -> SiteVersion:
        """Store a new version (None: no site), publish it retained and audit it. ``avoidance`` None keeps the
        current version's settings (an editor of the boundary need not know them). A refused site (422) or a
        concurrent edit on another replica (409) stores and publishes nothing."""
        filter_settings = (await self.latest()).avoidance if avoidance is None else self._avoidance(avoidance)
        model: Site | None = None
        if site is not None:
            check_site(site)
            try:
                model = Site.model_validate(site)  # the protocol's own model: what the robots accept
            except ValidationError as exc:
                raise SiteRefused(f"not a site the robots accept: {format_errors(exc)}", "bad_site") from None
        body = None if model is None else model.model_dump(mode="json")
        try:
            row = await asyncio.to_thread(
                store.append_site,
                self._engine,
                body,
                "api",
                actor.name or actor.subject,
                time.time(),
                False,
                filter_settings.model_dump(mode="json"),
            )
        except store.SiteConflict:
            why = "the site was changed at the same time elsewhere: try again"
            raise ServiceError(409, why, "site_conflict") from None
        assert row is not None
        version = self._adopt(SiteVersion.from_row(row))
        self.publish(version)
        self._audit.record(
            actor,
            "site",
            None,
            {"version": version.version, "configured": model is not None}
            | {"avoidance": filter_settings.model_dump(mode="json")}
            | ({} if model is None else {"boundary_points": len(model.boundary), "keepouts": len(model.keepouts)}),
        )
        log.info("site version %d set by %s%s", version.version, version.updated_by, "" if model else " (no site)")
        return version

    @staticmethod
    def _avoidance(avoidance: dict[str, Any]) -> AvoidanceSettings:
        try:
            return AvoidanceSettings.model_validate(avoidance)
        except ValidationError as exc:
            raise SiteRefused(f"not avoidance settings the robots accept: {format_errors(exc)}", "bad_site") from None

    # -- publishing ----------------------------------------------------------------------------------------
    def publish(self, version: SiteVersion | None = None) -> bool:
        """Retained, QoS 1 (paho queues it while disconnected and sends it after reconnecting)."""
        version = version or self.current
        if version is None:
            return False
        self.published += 1
        return self._publisher.publish(self._topic, dumps(version.message()), qos=QOS_SITE, retain=True)

    def on_connection_change(self, connected: bool) -> None:
        """Event loop: on each (re)connection, publish the version this server holds at once (a broker
        restarted without persistence has forgotten the retained site), then again if the database has a newer
        one (another replica's edit). The first publish does not wait for the database: a robot that connects
        meanwhile gets the site sooner, and nothing published on the topic after the connection (a test's own
        site) is overwritten by a late republish."""
        if not connected:
            return
        self.publish()
        if self._republish is None or self._republish.done():
            self._republish = asyncio.get_running_loop().create_task(self._refresh_and_publish(), name="site-publish")

    async def _refresh_and_publish(self) -> None:
        try:
            held = None if self.current is None else self.current.version
            newest = await self.latest()
            if newest.version != held:
                self.publish(newest)
        except Exception:
            log.exception("publishing the site failed")

    async def close(self) -> None:
        if self._republish is not None:
            self._republish.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._republish

    def tag_map(self) -> dict[int, SiteTag]:
        """The current site's wall tags by id (the alarms' localization check reads them on each frame)."""
        current = self.current
        return {} if current is None or current.site is None else {tag.id: tag for tag in current.site.tags}

    # -- the geofence on goals -----------------------------------------------------------------------------
    async def check_goal(self, command: str, args: dict[str, Any]) -> int:
        """The site version a goto/follow_path goal was checked against; 422 ``geofence`` when it leaves it."""
        version = await self.latest()
        fence = self._fence_of(version)
        if fence is not None:
            why = fence.goal_problem(command, args)
            if why is not None:
                detail = f"{command} refused by the geofence: {why} (site v{version.version})"
                raise ServiceError(422, detail, "geofence")
        return version.version

    def _fence_of(self, version: SiteVersion) -> ServerFence | None:
        if self._fence is None or self._fence[0] != version.version:
            self._fence = (version.version, None if version.site is None else ServerFence(version.site))
        return self._fence[1]
