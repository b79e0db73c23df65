"""Every database table (SQLAlchemy 2.0 typed declarative), one module per area. The schema itself is owned
by the Alembic migrations; importing this package registers every table on ``Base.metadata``."""

from __future__ import annotations

from backend.models.aggregates import AGG_TABLES, RESOLUTIONS, TELEMETRY_1M, TELEMETRY_1S, TELEMETRY_DIRTY
from backend.models.alarms import AlarmRow, AlarmRuleRow, AlarmTransitionRow
from backend.models.auth import ApiToken, User
from backend.models.base import Base, BigId
from backend.models.commands import CommandAckRow, CommandRow
from backend.models.enrolment import EnrolmentRow
from backend.models.events import EventRow
from backend.models.missions import MissionEventRow, MissionRow, MissionTransitionRow
from backend.models.robots import Robot
from backend.models.runs import MarkerRow, RunRow
from backend.models.safety import AuditRow, LeaseRow, SafetyLatchRow
from backend.models.site import SiteVersionRow
from backend.models.telemetry import TelemetryRow

__all__ = [
    "AGG_TABLES",
    "RESOLUTIONS",
    "TELEMETRY_1M",
    "TELEMETRY_1S",
    "TELEMETRY_DIRTY",
    "AlarmRow",
    "AlarmRuleRow",
    "AlarmTransitionRow",
    "ApiToken",
    "AuditRow",
    "Base",
    "BigId",
    "CommandAckRow",
    "CommandRow",
    "EnrolmentRow",
    "EventRow",
    "LeaseRow",
    "MarkerRow",
    "MissionEventRow",
    "MissionRow",
    "MissionTransitionRow",
    "Robot",
    "RunRow",
    "SafetyLatchRow",
    "SiteVersionRow",
    "TelemetryRow",
    "User",
]
