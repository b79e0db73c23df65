"""Units of the known streams' data fields: the one table that CSV exports, the API (``GET /api/units``)
and the dashboard's plot axes all read, so a unit is written down once.

Keys are field paths without list indices, dotted for nested objects (``euler_deg.yaw``); a path not in
the table takes the unit of its longest listed prefix (``euler_deg.yaw`` -> ``euler_deg``, ``accel[2]``
-> ``accel``), also after leading labels (``tag3.translation_mm[0]`` -> ``translation_mm``). An empty
string means dimensionless; a field not found has no known unit.
"""

from __future__ import annotations

import re

#: Every ``ts`` in the protocol: seconds since 1970-01-01 UTC (Unix epoch).
TIME_UNIT = "s (Unix epoch, UTC)"

STREAM_UNITS: dict[str, dict[str, str]] = {
    # Lighthouse frame, metres; yaw counter-clockwise from +x
    "position": {"x": "m", "y": "m", "z": "m", "yaw": "rad", "count": "", "seq": ""},
    "imu": {"accel": "m/s²", "gyro": "rad/s"},
    # tag pose in the camera frame (x right, y down, z forward); image coordinates in pixels
    "apriltag": {
        "frame_seq": "",
        "image_size": "px",
        "camera": "px",
        "detections": "",
        "tags": "",
        "tag_id": "",
        "translation_mm": "mm",
        "euler_deg": "deg",
        "rotation": "",
        "center": "px",
        "corners": "px",
        "decision_margin": "",
        "pose_error": "",
    },
    "lighthouse_geometry": {"base_stations.position": "m", "base_stations.rotation": ""},
}

_INDEX_RE = re.compile(r"\[\d+\]")


def unit_of(stream: str, field: str) -> str | None:
    """The unit of ``field`` (a path such as ``x``, ``accel[0]`` or ``euler_deg.yaw``), None when unknown.
    Bucketed columns (``x_min``, ``x_max``) have their field's unit."""
    table = STREAM_UNITS.get(stream)
    if table is None:
        return None
    path = _INDEX_RE.sub("", field)
    for suffix in ("_min", "_max"):
        if path.endswith(suffix) and path not in table and path[: -len(suffix)] in table:
            path = path[: -len(suffix)]
    parts = path.split(".")
    for first in range(len(parts)):  # a leading label the path may carry (the dashboard's ``tag3.``)
        for n in range(len(parts), first, -1):
            unit = table.get(".".join(parts[first:n]))
            if unit is not None:
                return unit
    return None
