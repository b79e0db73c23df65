"""Simulation of a robot: differential-drive kinematics and a small world of AprilTags."""
