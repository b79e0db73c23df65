"""The motion runner's timing and tolerances (robot_agent/motion/runner.py)."""

#: A goal fails when the last position fix is older than this (so the robot stands within 0.5 s of it).
FIX_SILENCE_S = 0.3
TICK_S = 0.025
IDLE_TICK_S = 0.2
MOTION_REPORT_PERIOD_S = 0.1
#: A goal that got no closer by STALL_PROGRESS_M within STALL_WINDOW_S is stalled.
STALL_WINDOW_S = 8.0
STALL_PROGRESS_M = 0.02
#: A goal the safety filter held back (another robot in the way) with no progress for this long is blocked.
BLOCKED_WINDOW_S = 10.0
#: Margin of the geofence's look-ahead beyond the kinematic stop time: one control period and a bit.
LOOKAHEAD_EXTRA_S = 0.1
DEFAULT_GOAL_SPEED_MPS = 0.15
