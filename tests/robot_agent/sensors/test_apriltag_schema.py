"""The apriltag stream's wire schema (fleet_protocol.AprilTagData) accepts the plugin's messages and
refuses malformed ones the way every other stream does (ProtocolError with a counter label)."""

from __future__ import annotations

import copy
import math
from typing import Any

import pytest

from fleet_protocol import ProtocolError, decode_telemetry, encode_telemetry
from robot_agent.vision.detector import TagDetector
from robot_agent.vision.settings import CaptureSettings
from robot_agent.vision.sim_camera import SimCamera, TagPlacement


@pytest.fixture(scope="module")
def message() -> dict[str, Any]:
    cam = SimCamera(CaptureSettings())
    tag = TagPlacement.facing(5, 0.15, 0.9, 0.1, 0.1, math.pi - 0.5)
    msg = TagDetector(tag_size_m=0.15, nthreads=1).message(cam.render((0.0, 0.0, 0.0), [tag]), cam.intrinsics, 7)
    assert len(msg["detections"]) == 1
    return msg


def test_plugin_message_round_trips(message: dict[str, Any]) -> None:
    decoded = decode_telemetry(encode_telemetry(3, message), "apriltag")
    assert decoded.seq == 3
    assert decoded.data == message


@pytest.mark.parametrize(
    "mutate",
    [
        lambda m: m.pop("frame_seq"),
        lambda m: m.__setitem__("frame_seq", -1),
        lambda m: m.__setitem__("image_size", [640]),
        lambda m: m["camera"].__setitem__("fx", 0),
        lambda m: m["detections"][0].__setitem__("corners", [[1, 2]] * 3),
        lambda m: m["detections"][0].__setitem__("corners", [[1, 2, 3]] * 4),
        lambda m: m["detections"][0].__setitem__("rotation", [[1, 0], [0, 1], [0, 0]]),
        lambda m: m["detections"][0].__setitem__("translation_mm", [1.0, 2.0]),
        lambda m: m["detections"][0]["euler_deg"].pop("yaw"),
        lambda m: m["detections"][0].__setitem__("tag_id", "five"),
        lambda m: m.__setitem__("detections", "none"),
    ],
)
def test_malformed_messages_are_refused(message: dict[str, Any], mutate: Any) -> None:
    bad = copy.deepcopy(message)
    mutate(bad)
    with pytest.raises(ProtocolError) as exc:
        decode_telemetry(encode_telemetry(1, bad), "apriltag")
    assert exc.value.reason == "bad_apriltag"


def test_non_finite_numbers_are_refused(message: dict[str, Any]) -> None:
    from pydantic import ValidationError

    from fleet_protocol import AprilTagData

    for path in (("translation_mm", 2), ("center", 0), ("decision_margin", None), ("pose_error", None)):
        bad = copy.deepcopy(message)
        det = bad["detections"][0]
        if path[1] is None:
            det[path[0]] = math.inf
        else:
            det[path[0]][path[1]] = math.nan
        with pytest.raises(ValidationError, match="finite"):
            AprilTagData.model_validate(bad)
    bad = copy.deepcopy(message)
    bad["detections"][0]["rotation"][1][1] = math.inf
    with pytest.raises(ValidationError, match="finite"):
        AprilTagData.model_validate(bad)
