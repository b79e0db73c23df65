"""Telemetry reads: points, pages, several robots over one range, and each stream's counts and gaps."""

from __future__ import annotations

from typing import Any, Literal, NotRequired

from pydantic import BaseModel, SerializerFunctionWrapHandler, model_serializer
from typing_extensions import TypedDict

#: the clock a history read places its points on: the robot's ``ts`` (default), or with ``recv_ts`` each
#: point also carries when the server received it (the server's clock)
TimeBase = Literal["ts", "recv_ts"]


class TelemetryPointJson(TypedDict):
    """A point as answered (its schema is the one OpenAPI shows): ``recv_ts`` only when asked for."""

    ts: float
    seq: int
    data: dict[str, Any]
    recv_ts: NotRequired[float | None]


class TelemetryPoint(BaseModel):
    #: the robot's clock (the message's ts); reads select and order by it
    ts: float
    seq: int
    data: dict[str, Any]
    #: ``time=recv_ts`` only: when the server received the message (its clock; the mean of a bucket's
    #: rows, or the last row's for ``bucket-last``); null where unknown (rows stored before the server
    #: recorded it). Left out of the answer otherwise.
    recv_ts: float | None = None

    @model_serializer(mode="wrap")
    def _drop_unasked_recv_ts(self, handler: SerializerFunctionWrapHandler) -> TelemetryPointJson:
        out: TelemetryPointJson = handler(self)
        if out.get("recv_ts", 0) is None and "recv_ts" not in self.model_fields_set:
            del out["recv_ts"]
        return out


class TelemetryPage(BaseModel):
    robot_id: str
    stream: str
    downsampled: bool
    #: ``none`` raw points; ``bucket-mean-minmax`` (position: per time bucket the mean of x/y/z plus
    #: ``x_min``/``x_max``... and the bucket's last yaw); ``bucket-last`` (other streams: the last point
    #: of each bucket).
    method: Literal["none", "bucket-mean-minmax", "bucket-last"]
    points: list[TelemetryPoint]


Source = Literal["raw", "1s", "1m"]


class HistoryPage(TelemetryPage):
    """One robot's stream. ``method``: ``none`` (stored rows), ``bucket-mean-minmax`` or ``bucket-last``."""

    #: where the points come from: raw rows and/or retention aggregates (per second, per minute)
    sources: list[Source] = ["raw"]
    #: bucket width in seconds when downsampled
    bucket_s: float | None = None
    #: the data fields kept (``fields=``), None: all
    fields: list[str] | None = None
    #: raw pages: pass as ``cursor`` to get the next page; None: this was the last page
    next_cursor: str | None = None


class HistorySet(BaseModel):
    """Several robots and streams over one time range (``GET /api/telemetry``)."""

    start: float | None
    end: float | None
    max_points: int
    series: list[HistoryPage]


class GapRange(BaseModel):
    """Inclusive ``seq`` range of one agent run (``boot``); lost ranges say why (``reason``) and when."""

    boot: str
    first: int
    last: int
    reason: str | None = None
    at: float | None = None


class StreamStats(BaseModel):
    stream: str
    count: int
    first_ts: float | None
    last_ts: float | None
    last_seq: int | None = None
    #: Sequence numbers never received (counted since this server started).
    gaps: int = 0
    #: Messages with a seq not above the last one (redeliveries, reordering) since this server started.
    out_of_order: int = 0
    #: Times the seq went back to 0 (agent restart).
    restarts: int = 0
    #: Gap repair, since this server started (``gaps`` above = open + repaired + lost + originals that
    #: came late). ``gaps_open``: missing and still being asked for; ``gaps_repaired``: brought back by the
    #: robot and stored; ``gaps_lost``: given up (the robot no longer had them, restarted without them,
    #: never answered, or they aged past its replay window): ``lost_ranges`` says which and why.
    gaps_open: int = 0
    gaps_repaired: int = 0
    gaps_lost: int = 0
    open_ranges: list[GapRange] = []
    lost_ranges: list[GapRange] = []
    #: the boot id of the robot's agent run that sent the newest message (null: an agent without one)
    boot: str | None = None
