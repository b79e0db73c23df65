"""The motion commands, registered like every other command: ``drive`` (velocity), ``goto``, ``follow_path``.

``drive`` returns wheel set-points, so the command handler's deadman, e-stop gate and link watchdog apply to
it as to the seed's drive commands. ``goto`` and ``follow_path`` hand the goal to the robot's
:class:`~robot_agent.motion.runner.MotionRunner`, which acks them itself when they end.
"""

from __future__ import annotations

from fleet_protocol import FollowPathArgs, GotoArgs, VelocityDriveArgs
from robot_agent.commands import SELF_ACKED, CommandHandler, CommandSpec, Drive, SelfAcked, register_command
from robot_agent.motion.runner import MotionRunner


def _runner(h: CommandHandler) -> MotionRunner:
    if not isinstance(h.motion, MotionRunner):
        raise RuntimeError("motion commands need the agent's motion runner")
    return h.motion


def _drive(args: VelocityDriveArgs, h: CommandHandler) -> Drive:
    runner = _runner(h)
    wheels = runner.kin.mix(args.linear, args.angular)
    runner.report_drive(h.current_command_id, wheels, args.linear, args.angular)
    return Drive(wheels.left, wheels.right, args.duration_s)


def _goto(args: GotoArgs, h: CommandHandler) -> SelfAcked:
    _runner(h).start_goto(h.current_command_id, args)
    return SELF_ACKED


def _follow_path(args: FollowPathArgs, h: CommandHandler) -> SelfAcked:
    _runner(h).start_path(h.current_command_id, args)
    return SELF_ACKED


register_command(CommandSpec("drive", VelocityDriveArgs, _drive, drives=True))
register_command(CommandSpec("goto", GotoArgs, _goto, drives=True))
register_command(CommandSpec("follow_path", FollowPathArgs, _follow_path, drives=True))
