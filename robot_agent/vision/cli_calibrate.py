"""``fleet-agent calibrate IMAGES... --board COLSxROWS --square-mm S [--write-config agent.toml]``.

Prints the calibration as one JSON object (fx, fy, cx, cy, dist_coeffs, rms_px, ...) and a readable
summary on stderr; ``--write-config`` stores the intrinsics in the agent config's camera entries.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import orjson


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="fleet-agent calibrate", description="Camera intrinsics from chessboard photos.")
    p.add_argument("images", nargs="+", metavar="IMAGE")
    p.add_argument("--board", required=True, metavar="COLSxROWS", help="inner corners, e.g. 9x6")
    p.add_argument("--square-mm", type=float, required=True, metavar="S", help="square edge in mm")
    p.add_argument("--write-config", type=Path, metavar="FILE.toml", help="write fx/fy/cx/cy into this config")
    return p


def main_calibrate(argv: Sequence[str] | None = None) -> int:
    """Exit status: 0 calibrated, 2 bad arguments or too few usable images."""
    args = build_parser().parse_args(argv)
    from robot_agent.vision.calibration import CalibrationError, calibrate, parse_board, write_camera_config

    try:
        board = parse_board(args.board)
    except ValueError as exc:
        print(f"fleet-agent calibrate: {exc}", file=sys.stderr)
        return 2
    import cv2

    images = []
    for path in args.images:
        img = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        if img is None:
            print(f"fleet-agent calibrate: cannot read image {path}; skipped", file=sys.stderr)
            continue
        images.append((path, img))
    try:
        result = calibrate(images, board, args.square_mm)
    except CalibrationError as exc:
        print(f"fleet-agent calibrate: {exc}", file=sys.stderr)
        return 2
    for name in result.images_rejected:
        print(f"fleet-agent calibrate: board not found in {name}; skipped", file=sys.stderr)
    print(
        f"fx={result.fx:.2f} fy={result.fy:.2f} cx={result.cx:.2f} cy={result.cy:.2f} "
        f"rms={result.rms_px:.3f} px from {len(result.images_used)} image(s) "
        f"at {result.width}x{result.height}",
        file=sys.stderr,
    )
    sys.stdout.write(orjson.dumps(result.as_dict()).decode() + "\n")
    if args.write_config is not None:
        try:
            updated = write_camera_config(args.write_config, result.config_values())
        except (CalibrationError, OSError, ValueError) as exc:
            print(f"fleet-agent calibrate: cannot write {args.write_config}: {exc}", file=sys.stderr)
            return 2
        print(
            f"wrote the intrinsics into {args.write_config} ({', '.join(updated)} sensor entries)",
            file=sys.stderr,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main_calibrate())
