"""``fleet-agent detect IMAGE... --tag-size M --camera FX,FY,CX,CY``: offline AprilTag detection.

Prints one JSON line per image in the ``apriltag`` stream schema (plus ``"image"``), so a calibration
can be checked against tags at measured distances without a robot.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

import orjson


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="fleet-agent detect", description="Detect AprilTags in images; one JSON line per image."
    )
    p.add_argument("images", nargs="+", metavar="IMAGE")
    p.add_argument("--tag-size", type=float, required=True, metavar="M", help="black square edge, metres")
    p.add_argument("--camera", required=True, metavar="FX,FY,CX,CY", help="intrinsics in pixels")
    p.add_argument("--family", default="tag36h11")
    p.add_argument("--dist", default="", metavar="K1,K2,P1,P2[,K3]", help="distortion coefficients")
    p.add_argument("--quad-decimate", type=float, default=1.0, help="1.0 = full resolution (most accurate)")
    p.add_argument("--nthreads", type=int, default=None)
    return p


def main_detect(argv: Sequence[str] | None = None) -> int:
    """Exit status: 0 all images read, 1 some could not be read, 2 bad arguments."""
    args = build_parser().parse_args(argv)
    from robot_agent.vision.settings import Intrinsics

    try:
        camera = Intrinsics.parse(args.camera)
        dist = [float(v) for v in args.dist.split(",") if v.strip()]
    except ValueError as exc:
        print(f"fleet-agent detect: {exc}", file=sys.stderr)
        return 2
    if args.tag_size <= 0:
        print("fleet-agent detect: --tag-size must be positive", file=sys.stderr)
        return 2

    import cv2

    from robot_agent.vision.detector import TagDetector

    try:
        detector = TagDetector(
            family=args.family,
            tag_size_m=args.tag_size,
            nthreads=args.nthreads,
            quad_decimate=args.quad_decimate,
            dist_coeffs=dist,
        )
    except Exception as exc:  # unknown family and the like
        print(f"fleet-agent detect: {exc}", file=sys.stderr)
        return 2
    status = 0
    try:
        for index, path in enumerate(args.images):
            image = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
            if image is None:
                print(f"fleet-agent detect: cannot read image {path}", file=sys.stderr)
                status = 1
                continue
            msg = {"image": path, **detector.message(image, camera, index)}
            sys.stdout.write(orjson.dumps(msg).decode() + "\n")
            sys.stdout.flush()
    finally:
        detector.close()
    return status


if __name__ == "__main__":
    raise SystemExit(main_detect())
