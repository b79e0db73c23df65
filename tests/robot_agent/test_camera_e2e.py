"""Camera and AprilTag end to end: a real ``fleet-agent --simulate --camera`` process against a real broker.

The simulated robot starts at (1, 0) facing east: tag 0 hangs on the east wall (x = 2 m) at the camera's
height, so it is straight ahead, 1 m away. A probe receives the binary camera frames and the apriltag
stream and checks that detections refer to frames it has received, that the detected tag is the one in
view at the right distance, and that the JPEG of that frame really shows the tag where the detection says.
"""

from __future__ import annotations

import cv2
import numpy as np
import orjson

from fleet_protocol import AprilTagData, Topics, decode_camera_frame, decode_status
from robot_agent.vision.detector import TagDetector
from robot_agent.vision.settings import Intrinsics
from tests.support.mqtt import MqttProbe
from tests.support.procs import wait_for

T = Topics()
RID = "cam-e2e"


def _frames(probe: MqttProbe) -> dict[int, bytes]:
    out = {}
    for m in probe.matching(lambda m: m.topic == T.camera(RID)):
        header, jpeg = decode_camera_frame(m.payload)
        assert (header.width, header.height, header.format) == (640, 480, "jpeg")
        out[header.frame_seq] = jpeg
    return out


def _detections(probe: MqttProbe) -> list[AprilTagData]:
    msgs = []
    for m in probe.matching(lambda m: m.topic == T.telemetry(RID, "apriltag")):
        body = orjson.loads(m.payload)
        msgs.append(AprilTagData.model_validate(body["data"]))
    return msgs


def test_camera_frames_and_apriltag_detections_from_a_real_agent(spawn_agent, mqtt_probe) -> None:
    probe = mqtt_probe(T.status(RID), T.camera(RID), T.telemetry(RID, "apriltag"))
    spawn_agent(RID, "--camera", "--start-pose=1,0,0")

    def matched() -> list[AprilTagData]:
        frames = _frames(probe)
        return [d for d in _detections(probe) if d.frame_seq in frames and d.detections]

    wait_for(lambda: len(matched()) >= 3, 60, what="detections matching received frames")

    status = decode_status(
        probe.wait(lambda m: m.topic == T.status(RID) and orjson.loads(m.payload)["online"], 5).payload
    )
    assert {"camera", "apriltag"} <= set(status.capabilities.sensors)
    assert status.capabilities.sensors[:2] == ["position", "imu"]
    assert status.sensors["camera"].ok and status.sensors["apriltag"].ok

    frames = _frames(probe)
    seqs = [decode_camera_frame(m.payload)[0].frame_seq for m in probe.matching(lambda m: m.topic == T.camera(RID))]
    assert seqs == sorted(set(seqs)), "camera frame_seq must increase and never repeat"
    tag_msgs = _detections(probe)
    tag_seqs = [d.frame_seq for d in tag_msgs]
    assert tag_seqs == sorted(set(tag_seqs))

    # The robot stands still facing tag 0: every frame shows it, straight ahead and 1 m away.
    for msg in tag_msgs:
        assert [d.tag_id for d in msg.detections] == [0], msg
        assert msg.image_size == [640, 480]
        assert msg.camera.model_dump() == {"fx": 500.0, "fy": 500.0, "cx": 320.0, "cy": 240.0}
        (det,) = msg.detections
        x, y, z = det.translation_mm
        assert abs(z - 1000.0) < 30.0 and abs(x) < 30.0 and abs(y) < 30.0, det.translation_mm
        assert det.family == "tag36h11"

    # The JPEG carrying a detection's frame_seq shows the tag exactly where the detection puts it.
    detector = TagDetector(tag_size_m=0.1, nthreads=1)
    try:
        for msg in matched()[:2]:
            image = cv2.imdecode(np.frombuffer(frames[msg.frame_seq], np.uint8), cv2.IMREAD_COLOR)
            assert image is not None and image.shape == (480, 640, 3)
            found = {d["tag_id"]: d for d in detector.detect(image, Intrinsics(500.0, 500.0, 320.0, 240.0))}
            assert set(found) == {0}
            corners = np.asarray(found[0]["corners"])
            assert np.abs(corners - np.asarray(msg.detections[0].corners)).max() < 2.0
    finally:
        detector.close()
