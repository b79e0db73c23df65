"""Calibration on chessboards rendered with known intrinsics, the calibrate CLI and the config writer."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import cv2
import numpy as np
import orjson
import pytest

from robot_agent.vision.calibration import CalibrationError, calibrate, parse_board, write_camera_config
from robot_agent.vision.cli_calibrate import main_calibrate

TRUE_K = np.array([[620.0, 0.0, 331.0], [0.0, 612.0, 236.0], [0.0, 0.0, 1.0]])
BOARD = (9, 6)  # inner corners
SQUARE_MM = 25.0


def rot(ax: float, ay: float, az: float) -> np.ndarray:
    r, _ = cv2.Rodrigues(np.array([ax, ay, az], dtype=np.float64))
    return r


def render_board(
    r: np.ndarray,
    t: np.ndarray,
    k: np.ndarray = TRUE_K,
    size: tuple[int, int] = (640, 480),
    board: tuple[int, int] = BOARD,
    square_mm: float = SQUARE_MM,
) -> np.ndarray:
    """The chessboard plane (inner corner (0,0) at the origin, metres) seen with pose (r, t)."""
    cols, rows = board
    p, margin = 40, 40  # texture pixels per square, white margin
    tex = np.full((margin * 2 + p * (rows + 1), margin * 2 + p * (cols + 1)), 255, np.uint8)
    for j in range(rows + 1):
        for i in range(cols + 1):
            if (i + j) % 2 == 0:
                tex[margin + j * p : margin + (j + 1) * p, margin + i * p : margin + (i + 1) * p] = 0
    sq = square_mm / 1000.0
    # texture pixel (OpenCV centres on integers) -> board plane metres
    off = margin + p - 0.5
    tex_to_plane = np.array([[sq / p, 0, -off * sq / p], [0, sq / p, -off * sq / p], [0, 0, 1]])
    plane_to_img = k @ np.column_stack([r[:, 0], r[:, 1], t])
    h = plane_to_img @ tex_to_plane
    return cv2.warpPerspective(tex, h, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=128)


def views() -> list[np.ndarray]:
    out = []
    centre = np.array([0.1, 0.0625, 0.0])  # middle of the 9x6 inner-corner grid
    for ax, ay, az, dist in (
        (0.0, 0.0, 0.0, 0.55),
        (0.45, 0.0, 0.05, 0.5),
        (-0.45, 0.1, 0.0, 0.5),
        (0.0, 0.5, -0.05, 0.55),
        (0.1, -0.5, 0.0, 0.5),
        (0.35, 0.35, 0.1, 0.5),
        (-0.3, -0.35, -0.1, 0.55),
        (0.2, -0.2, 0.3, 0.45),
        (-0.25, 0.3, -0.2, 0.6),
        (0.4, -0.1, 0.15, 0.45),
    ):
        r = rot(ax, ay, az)
        t = np.array([0.0, 0.0, dist]) - r @ centre
        out.append(render_board(r, t))
    return out


def test_parse_board() -> None:
    assert parse_board("9x6") == (9, 6)
    assert parse_board(" 7X5 ") == (7, 5)
    for bad in ("9", "9x", "1x5", "a x b"):
        with pytest.raises(ValueError):
            parse_board(bad)


def test_recovers_known_intrinsics() -> None:
    res = calibrate([(f"v{i}", img) for i, img in enumerate(views())], BOARD, SQUARE_MM)
    assert len(res.images_used) == 10 and res.images_rejected == []
    assert res.fx == pytest.approx(620.0, rel=0.02)
    assert res.fy == pytest.approx(612.0, rel=0.02)
    assert res.cx == pytest.approx(331.0, rel=0.02)
    assert res.cy == pytest.approx(236.0, rel=0.02)
    assert res.rms_px < 0.5
    assert (res.width, res.height) == (640, 480)


def test_too_few_views_is_an_error() -> None:
    blank = np.full((480, 640), 128, np.uint8)
    with pytest.raises(CalibrationError, match="at least 3 views"):
        calibrate([("a", views()[0]), ("b", blank)], BOARD, SQUARE_MM)


def test_cli_prints_and_writes_config(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    paths = []
    for i, img in enumerate(views()[:8]):
        p = tmp_path / f"board{i}.png"
        cv2.imwrite(str(p), img)
        paths.append(str(p))
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((480, 640), 128, np.uint8))
    config = tmp_path / "agent.toml"
    config.write_text(
        "# my robot\n"
        'robot_id = "r7"\n\n'
        "[[sensors]]\n"
        'type = "position"\n'
        "rate_hz = 20.0\n\n"
        "[[sensors]]\n"
        'type = "apriltag"\n'
        "tag_size_m = 0.15\n"
        "fx = 1.0  # stale\n\n"
        "[[sensors]]\n"
        'type = "camera"\n'
        "jpeg_quality = 70\n"
        "\n[motors]\n"
        "max_speed_mps = 0.3\n"
    )
    rc = main_calibrate([*paths, str(blank), "--board", "9x6", "--square-mm", "25", "--write-config", str(config)])
    assert rc == 0
    out, err = capsys.readouterr()
    res = orjson.loads(out.strip())
    assert res["fx"] == pytest.approx(620.0, rel=0.02)
    assert res["images_rejected"] == [str(blank)]
    assert "board not found" in err
    cfg = tomllib.loads(config.read_text())
    assert cfg["robot_id"] == "r7" and cfg["motors"] == {"max_speed_mps": 0.3}
    pos, tag, cam = cfg["sensors"]
    assert pos == {"type": "position", "rate_hz": 20.0}
    for entry in (tag, cam):
        assert entry["fx"] == pytest.approx(res["fx"], abs=1e-3)
        assert entry["cy"] == pytest.approx(res["cy"], abs=1e-3)
        assert (entry["width"], entry["height"]) == (640, 480)
        assert len(entry["dist_coeffs"]) == 5
    assert tag["tag_size_m"] == 0.15 and cam["jpeg_quality"] == 70
    assert "# my robot" in config.read_text()
    # the written config is accepted by the plugins' config models
    from robot_agent.sensors.apriltag import AprilTagConfig
    from robot_agent.sensors.camera import CameraConfig

    assert AprilTagConfig.model_validate(tag).intrinsics().fx == pytest.approx(res["fx"], abs=1e-3)
    CameraConfig.model_validate(cam)


def test_write_config_creates_a_camera_entry(tmp_path: Path) -> None:
    path = tmp_path / "new.toml"
    assert write_camera_config(path, {"fx": 600.5, "fy": 601.0, "width": 640, "dist_coeffs": [0.1, -0.2]}) == ["camera"]
    assert tomllib.loads(path.read_text()) == {
        "sensors": [{"type": "camera", "fx": 600.5, "fy": 601.0, "width": 640, "dist_coeffs": [0.1, -0.2]}]
    }


def test_write_config_refuses_invalid_toml(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text("this is = = not toml\n")
    with pytest.raises(tomllib.TOMLDecodeError):
        write_camera_config(path, {"fx": 1.0})
    assert path.read_text() == "this is = = not toml\n"


def test_cli_bad_board(capsys: pytest.CaptureFixture[str]) -> None:
    assert main_calibrate(["x.png", "--board", "nine", "--square-mm", "25"]) == 2
    assert "COLSxROWS" in capsys.readouterr().err


def test_board_render_matches_projection() -> None:
    """The synthetic board really has the intrinsics the test claims (guards the renderer itself)."""
    r, t = rot(0.3, -0.2, 0.1), np.array([-0.1, -0.06, 0.5])
    img = render_board(r, t)
    found, corners = cv2.findChessboardCorners(img, BOARD)
    assert found
    corners = cv2.cornerSubPix(
        img, corners, (7, 7), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    )
    obj = np.zeros((54, 3), np.float32)
    obj[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2) * 0.025
    proj, _ = cv2.projectPoints(obj, cv2.Rodrigues(r)[0], t, TRUE_K, None)
    err = np.linalg.norm(proj.reshape(-1, 2) - corners.reshape(-1, 2), axis=1)
    # the detected order may start at either end of the grid
    err_rev = np.linalg.norm(proj.reshape(-1, 2) - corners.reshape(-1, 2)[::-1], axis=1)
    assert min(err.max(), err_rev.max()) < 0.3
    assert math.isfinite(float(err.mean()))
