"""Missions: coverage and formation plans, their live state, stepping, re-planning and replica ownership."""
