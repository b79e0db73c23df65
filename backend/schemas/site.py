"""The site the fleet works in and the units of the telemetry fields (``/api/site``, ``GET /api/units``).

The site's API names are the protocol's (:class:`fleet_protocol.motion.Site`: ``keepouts``, ``tags`` with
``size_m``): what an admin PUTs is what the robots receive."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, StrictBool, WithJsonSchema

from fleet_protocol.motion import MAX_COORDINATE_M, FiniteNumber
from fleet_protocol.neighbours import AvoidanceSettings
from fleet_protocol.units import TIME_UNIT

#: Within the protocol's limits, and small enough that a site always fits in one request body
#: (FLEET_MAX_BODY_BYTES, 64 KiB by default): a pool needs a few dozen corners and tags at most.
MAX_SITE_POLYGON_POINTS = 200
MAX_SITE_KEEPOUTS = 20
MAX_SITE_TAGS = 100

#: The wall tags are tag36h11 (the detector's family): ids 0-586. Any other id cannot be printed.
TAG_ID_MAX = 586

#: Metres, a JSON number (never a boolean), finite and bounded, in one Field so that OpenAPI says
#: minimum/maximum (the protocol's nested Annotated renders them as unknown "ge"/"le" keys)
Coordinate = Annotated[float, Field(strict=True, ge=-MAX_COORDINATE_M, le=MAX_COORDINATE_M, allow_inf_nan=False)]
#: [x, y] pairs as plain arrays (a tuple's prefixItems is mangled in FastAPI's OpenAPI 3.1 output)
Point = Annotated[list[Coordinate], Field(min_length=2, max_length=2)]
PolygonIn = Annotated[list[Point], Field(min_length=3, max_length=MAX_SITE_POLYGON_POINTS)]
PointOut = Annotated[list[float], Field(min_length=2, max_length=2)]


def _plain_integer(v: Any) -> Any:
    """JSON Schema's integer includes 3.0 but never ``true`` or ``"3"``: lax parsing would read them as 1
    and 3 (and a string id that looks like a number would lose its text)."""
    if isinstance(v, bool | str):
        raise ValueError("must be an integer number")
    return v


Integer = Annotated[int, BeforeValidator(_plain_integer)]
#: a rotation matrix's entries lie in [-1, 1] (a hair of slack for a calibration's rounding)
RotationEntry = Annotated[float, Field(strict=True, ge=-1.000001, le=1.000001, allow_inf_nan=False)]
Row3 = Annotated[list[RotationEntry], Field(min_length=3, max_length=3)]
#: a Lighthouse channel number (the JSON and every database take it; a 20-digit one broke the store)
StationNumber = Annotated[
    int,
    BeforeValidator(_plain_integer),
    Field(ge=0, le=2**31 - 1),
    # said outright: inside the union, pydantic would write the bounds as unknown "ge"/"le" keys
    WithJsonSchema({"type": "integer", "minimum": 0, "maximum": 2**31 - 1}),
]


class BaseStationIn(BaseModel):
    """A Lighthouse base station: its id (channel), position (metres) and rotation matrix (3 x 3)."""

    model_config = ConfigDict(extra="forbid")

    id: StationNumber | Annotated[str, Field(min_length=1, max_length=64)]
    position: Annotated[list[Coordinate], Field(min_length=3, max_length=3)]
    rotation: Annotated[list[Row3], Field(min_length=3, max_length=3)]


class TagPose(BaseModel):
    """Where a wall tag is (metres, Lighthouse frame) and which way its face looks (yaw, radians)."""

    model_config = ConfigDict(extra="forbid")

    x: Coordinate
    y: Coordinate
    z: Coordinate = 0.0
    yaw: FiniteNumber = Field(default=0.0, ge=-7.0, le=7.0)


class SiteTagIn(BaseModel):
    model_config = ConfigDict(extra="forbid")

    id: Integer = Field(ge=0, le=TAG_ID_MAX, description="tag36h11 id (0-586), unique in the site")
    size_m: FiniteNumber = Field(gt=0.0, le=10.0, description="printed size of the black square, metres")
    pose: TagPose


_AVOIDANCE_DEFAULTS = AvoidanceSettings()


class AvoidanceIn(BaseModel):
    """The robots' safety filter (issue 31, docs/safety.md): it keeps every pair of robots at least the site's
    ``min_separation_m`` plus ``margin_m`` (and more with speed and a neighbour's stale fix) apart. The bounds
    are the protocol's (:class:`fleet_protocol.neighbours.AvoidanceSettings`)."""

    model_config = ConfigDict(extra="forbid")

    enabled: StrictBool = Field(default=True, description="false: robots drive without the filter (not advised)")
    margin_m: FiniteNumber = Field(
        default=_AVOIDANCE_DEFAULTS.margin_m, ge=0.0, le=2.0, description="added to min_separation_m, metres"
    )
    creep_mps: FiniteNumber = Field(
        default=_AVOIDANCE_DEFAULTS.creep_mps,
        ge=0.0,
        le=0.5,
        description="the speed a robot keeps near a neighbour whose pose is stale, or hearing no poses, m/s",
    )


class SiteUpdate(BaseModel):
    """A new version of the site (``PUT /api/site``, admin). The rules OpenAPI cannot state are checked by the
    server and refused with 422 and a ``code``: polygons must be simple, with an area (``bad_polygon``);
    keep-outs lie inside the boundary (``keepout_outside_boundary``); tag ids are unique (``duplicate_tag``)."""

    model_config = ConfigDict(extra="forbid")

    boundary: PolygonIn = Field(description="[x, y] corners in metres (the last joins the first)")
    keepouts: list[PolygonIn] = Field(default_factory=list, max_length=MAX_SITE_KEEPOUTS)
    geofence_margin_m: FiniteNumber = Field(default=0.15, ge=0.0, le=10.0)
    min_separation_m: FiniteNumber = Field(default=0.3, ge=0.0, le=10.0)
    base_stations: list[BaseStationIn] = Field(default_factory=list, max_length=16)
    tags: list[SiteTagIn] = Field(default_factory=list, max_length=MAX_SITE_TAGS)
    avoidance: AvoidanceIn | None = Field(
        default=None, description="the robots' safety filter; omitted: the current version's settings are kept"
    )


class SitePublic(BaseModel):
    """The current site. With no site (``configured`` false: no fence) the lists are empty."""

    boundary: list[PointOut] = Field(description="[x, y] corners in metres; empty when there is no site")
    keepouts: list[list[PointOut]] = Field(default_factory=list)
    geofence_margin_m: float | None = None
    min_separation_m: float | None = None
    base_stations: list[BaseStationIn] = Field(default_factory=list)
    tags: list[SiteTagIn] = Field(default_factory=list)
    #: the robots' safety filter, published with the site (also with "no site": robots keep apart without a fence)
    avoidance: AvoidanceIn = Field(default_factory=AvoidanceIn)
    #: false: "no site" was set (DELETE /api/site): robots have no fence
    configured: bool = True
    frame: str = "lighthouse"
    units: str = "m"
    #: where this version came from: ``setting`` (FLEET_POOL_BOUNDARY, seeded on the first start) or ``api``
    source: Literal["setting", "api"] = "setting"
    #: grows by one with each change; robots report the version they checked a goal against
    version: int
    updated_by: str
    updated_at: float = Field(description="epoch seconds")


class UnitsPublic(BaseModel):
    """Units per stream and field path (no list indices; nested objects dotted). "" = dimensionless."""

    time: str = TIME_UNIT
    streams: dict[str, dict[str, str]]
