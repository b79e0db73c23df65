"""The distance a ``too_close`` / ``hand_near`` event reports: to the millimetre, never up to the limit."""

from __future__ import annotations

from backend.services.missions.book import mm_below


def test_a_distance_just_under_the_limit_never_reads_as_the_limit() -> None:
    # 0.2996 m rounded to the millimetre is 0.3: "closer than 0.3 m (0.3 m)", seen in a clean-clone run
    assert round(0.2996, 3) == 0.3
    assert mm_below(0.2996) == 0.299 < 0.3
    assert mm_below(0.25) == 0.25 and mm_below(0.0) == 0.0
