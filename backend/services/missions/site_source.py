"""Where the missions read the site (boundary, keep-outs, geofence margin, minimum separation) from: the site
service's current version (``PUT /api/site``, published retained to the robots)."""

from __future__ import annotations

from typing import Protocol

from backend.core.errors import ServiceError
from backend.services.site.service import SiteService
from fleet_protocol import Site


class SiteSource(Protocol):
    def current(self) -> Site: ...

    def version(self) -> int: ...


class ServedSite:
    """The current site; with "no site" (``DELETE /api/site``) there is no fence to plan inside, so a mission
    is refused (409 ``no_site``) rather than planned over the whole water."""

    def __init__(self, service: SiteService) -> None:
        self._service = service

    def current(self) -> Site:
        version = self._service.current
        if version is None or version.site is None:
            raise ServiceError(409, "no site is set: missions plan inside the site (PUT /api/site first)", "no_site")
        return version.site

    def version(self) -> int:
        """The current site's version (0: none), which a mission's run records."""
        current = self._service.current
        return current.version if current is not None else 0
