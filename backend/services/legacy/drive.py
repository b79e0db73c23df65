"""A velocity ``drive`` for a robot on the old framework: the nearest seed command, behind a dead band.

The seed's strings carry no speed: ``move_forward`` is full speed. So a small stick deflection must not
become one. Each axis is measured in units of its dead band; below one on both axes the robot hears
``stop``; otherwise the larger one wins (forward/backward for ``linear``, left/right for ``angular``,
counter-clockwise = left). The server's deadman (``duration_s``) and the e-stop apply as to every seed drive.
"""

from __future__ import annotations

from fleet_protocol import CommandName

#: |linear| below this (m/s) is no forward/backward request (a fifth of a typical 0.25 m/s top speed)
LEGACY_DEAD_BAND_LINEAR_MPS = 0.05
#: |angular| below this (rad/s) is no turn request
LEGACY_DEAD_BAND_ANGULAR_RPS = 0.3


def seed_command_for(linear: float, angular: float) -> str:
    """The seed command nearest to (linear m/s, angular rad/s): a drive string, or ``stop`` in the dead band."""
    lin = abs(linear) / LEGACY_DEAD_BAND_LINEAR_MPS
    ang = abs(angular) / LEGACY_DEAD_BAND_ANGULAR_RPS
    if lin < 1.0 and ang < 1.0:
        return CommandName.STOP.value
    if lin >= ang:
        return (CommandName.MOVE_FORWARD if linear > 0 else CommandName.MOVE_BACKWARD).value
    return (CommandName.TURN_LEFT if angular > 0 else CommandName.TURN_RIGHT).value
