"""Camera frames: binary payload = magic, header length, JSON header, JPEG bytes."""

from __future__ import annotations

import struct
from typing import Literal

from pydantic import Field

from fleet_protocol.codec import _load_json, _validate
from fleet_protocol.core import MAX_CAMERA_PAYLOAD_BYTES, ProtocolError, _Wire

CAMERA_MAGIC = b"MFC1"
_CAMERA_HDR = struct.Struct(">4sI")
#: a frame's ``ts`` (epoch seconds) is below this (2106): the server keeps frames under their ts in
#: nanoseconds (19 digits, MCAP's u64 log time), so 1e300, a negative, NaN or infinity is a bad frame
MAX_FRAME_TS_S = 2.0**32


class CameraHeader(_Wire):
    frame_seq: int = Field(ge=0)
    ts: float = Field(ge=0.0, lt=MAX_FRAME_TS_S)
    width: int = Field(gt=0, le=10000)
    height: int = Field(gt=0, le=10000)
    format: Literal["jpeg"] = "jpeg"


def encode_camera_frame(header: CameraHeader, jpeg: bytes) -> bytes:
    hdr = header.model_dump_json().encode()
    return _CAMERA_HDR.pack(CAMERA_MAGIC, len(hdr)) + hdr + jpeg


def decode_camera_frame(payload: bytes) -> tuple[CameraHeader, bytes]:
    if len(payload) > MAX_CAMERA_PAYLOAD_BYTES:
        raise ProtocolError("oversize", f"{len(payload)} bytes")
    if len(payload) < _CAMERA_HDR.size or payload[:4] != CAMERA_MAGIC:
        raise ProtocolError("bad_camera", "missing frame header")
    _, hlen = _CAMERA_HDR.unpack_from(payload)
    end = _CAMERA_HDR.size + hlen
    if hlen > 4096 or end > len(payload):
        raise ProtocolError("bad_camera", "bad header length")
    header = _validate(CameraHeader, _load_json(payload[_CAMERA_HDR.size : end]), "bad_camera")
    return header, payload[end:]
