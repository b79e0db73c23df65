"""The API shapes of a robot's enrolment (``POST /api/enrol``, issue 29 #3)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from backend.core.enrolment import TOKEN_PATTERN


class EnrolRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")

    #: the single-use token ``fleet-server robots add ID`` printed (in the body: never in a URL or a log)
    token: str = Field(pattern=TOKEN_PATTERN)


class EnrolAnswer(BaseModel):
    """What the robot's agent needs (``fleet-agent enrol`` writes it into its config)."""

    robot_id: str
    #: the broker account (the ACL's convention: the robot id)
    username: str
    password: str
    #: the broker to connect to; None: discover it (by the beacon proving ``fleet_key``)
    broker: str | None
    #: the base station's fleet key, 64 hex digits: the pin that discovery checks
    fleet_key: str
    #: the CA certificate (PEM) of the broker's TLS listener, when the lab uses TLS
    tls_ca: str | None
