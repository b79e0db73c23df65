"""Camera capture, the simulated camera, AprilTag detection and camera calibration.

Everything here that needs numpy, OpenCV or dt-apriltags (the ``vision`` extra) imports them inside the
modules that use them, never from this package's ``__init__``: the agent must start on a robot without
that extra when no camera or apriltag sensor is configured.
"""
