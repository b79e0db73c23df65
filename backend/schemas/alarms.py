"""Alarms: each alarm with its transitions, and the built-in rules with their thresholds."""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Any, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, StrictBool, create_model

from backend.core.alarm_rules import RULES
from fleet_protocol import StrictNumber


class AlarmTransition(BaseModel):
    ts: float
    state: str
    by: str


class AlarmPublic(BaseModel):
    """An alarm: ``active`` -> ``acknowledged`` -> ``cleared``; ``robot_id`` null for a fleet-wide one."""

    id: int
    robot_id: str | None
    kind: str
    severity: Literal["info", "warning", "critical"]
    state: Literal["active", "acknowledged", "cleared"]
    message: str
    detail: dict[str, Any]
    raised_at: float
    acked_at: float | None = None
    acked_by: str | None = None
    cleared_at: float | None = None
    transitions: list[AlarmTransition] = Field(default_factory=list)


class AlarmRulePublic(BaseModel):
    kind: str
    severity: str
    description: str
    event: bool
    enabled: bool
    params: dict[str, float]


class AlarmRuleUpdateBase(BaseModel):
    """What every rule's update has; each rule's own model (below) narrows ``kind`` and ``params``."""

    model_config = ConfigDict(extra="forbid")

    kind: str
    enabled: StrictBool = True  # a JSON true/false: 0 or "no" is refused, never read as a switch
    params: BaseModel


def _rule_update(kind: str, params: tuple[str, ...]) -> type[AlarmRuleUpdateBase]:
    """The body that changes one rule: only that rule's own parameters (the schema says which)."""
    camel = "".join(part.title() for part in kind.split("_"))
    fields: dict[str, Any] = {p: (StrictNumber | None, None) for p in params}
    param_model = create_model(f"{camel}Params", __config__=ConfigDict(extra="forbid"), **fields)
    narrowed: dict[str, Any] = {
        "kind": (Literal.__getitem__(kind), ...),
        "params": (param_model, Field(default_factory=param_model)),
    }
    return create_model(f"{camel}RuleUpdate", __base__=AlarmRuleUpdateBase, **narrowed)


_RULE_UPDATES = tuple(_rule_update(rule.kind, tuple(rule.params)) for rule in RULES.values())

if TYPE_CHECKING:
    AlarmRuleUpdate = AlarmRuleUpdateBase
else:
    #: ``PUT /api/alarm-rules``: one rule, by its ``kind``, with only the parameters that rule has
    AlarmRuleUpdate = Annotated[Union[_RULE_UPDATES], Field(discriminator="kind")]  # noqa: UP007
