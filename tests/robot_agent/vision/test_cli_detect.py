"""``fleet-agent detect``: JSON lines in the apriltag stream schema for image files."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import orjson
import pytest

from fleet_protocol import AprilTagData
from robot_agent.vision.cli_detect import main_detect
from robot_agent.vision.settings import CaptureSettings
from robot_agent.vision.sim_camera import SimCamera, TagPlacement


def test_detect_prints_one_json_line_per_image(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    settings = CaptureSettings(fx=600.0, fy=600.0, cx=321.0, cy=239.0)
    cam = SimCamera(settings)
    scenes = {
        "one.png": [TagPlacement.facing(0, 0.1, 0.8, 0.1, 0.1, math.pi - 0.6)],
        "two.png": [
            TagPlacement.facing(7, 0.1, 0.7, -0.15, 0.12, math.pi + 0.6),
            TagPlacement.facing(586, 0.1, 1.2, 0.25, 0.1, math.pi - 0.7),
        ],
        "none.png": [],
    }
    paths = []
    for name, tags in scenes.items():
        p = tmp_path / name
        cv2.imwrite(str(p), cam.render((0.0, 0.0, 0.0), tags))
        paths.append(str(p))

    rc = main_detect([*paths, "--tag-size", "0.1", "--camera", "600,600,321,239", "--family", "tag36h11"])
    assert rc == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 3
    for index, (line, (name, tags)) in enumerate(zip(lines, scenes.items(), strict=True)):
        raw = orjson.loads(line)
        assert raw["image"].endswith(name)
        msg = AprilTagData.model_validate(raw)
        assert msg.frame_seq == index
        assert msg.camera.model_dump() == {"fx": 600.0, "fy": 600.0, "cx": 321.0, "cy": 239.0}
        assert msg.image_size == [640, 480]
        truth = {t.tag_id: t for t in cam.truth((0.0, 0.0, 0.0), tags)}
        assert sorted(d.tag_id for d in msg.detections) == sorted(truth)
        for d in msg.detections:
            t = truth[d.tag_id]
            err = np.linalg.norm(np.asarray(d.translation_mm) / 1000.0 - t.translation)
            assert err <= 0.03 * t.distance


def test_detect_reports_unreadable_images(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = tmp_path / "g.png"
    cv2.imwrite(str(good), np.full((120, 160), 128, np.uint8))
    rc = main_detect([str(tmp_path / "missing.png"), str(good), "--tag-size", "0.1", "--camera", "100,100,80,60"])
    assert rc == 1
    out, err = capsys.readouterr()
    assert "cannot read image" in err and "missing.png" in err
    [line] = out.strip().splitlines()
    assert orjson.loads(line)["detections"] == []


@pytest.mark.parametrize("camera", ["1,2,3", "a,b,c,d", "0,500,320,240"])
def test_detect_rejects_bad_camera(camera: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main_detect(["x.png", "--tag-size", "0.1", "--camera", camera]) == 2
    assert "fleet-agent detect" in capsys.readouterr().err
