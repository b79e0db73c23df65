"""The MCAP writer of a run, one message at a time: Foxglove's protobuf schemas for poses, camera frames,
annotations, transforms and logs, JSON with a JSON schema for every other stream and for commands, and the
robot's clock offsets applied to each log time. mcap.py feeds it a whole run in time order."""

from __future__ import annotations

import bisect
import math
from typing import IO, Any

import orjson
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from google.protobuf.message import Message
from google.protobuf.timestamp_pb2 import Timestamp
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import build_file_descriptor_set

from backend.services.runs.frames import StoredFrame

#: the frame poses, base stations and tags are in (the Lighthouse frame of the pool)
POOL_FRAME = "pool"


PROFILE = "mollusca-fleet"


_JSON_TYPES: tuple[tuple[type, str], ...] = (
    (bool, "boolean"),
    (int, "integer"),
    (float, "number"),
    (str, "string"),
    (list, "array"),
    (dict, "object"),
)


def json_schema_of(example: dict[str, Any]) -> dict[str, Any]:
    """A JSON schema naming the fields of a stream's first message (more fields are allowed)."""
    props: dict[str, Any] = {}
    for key, value in example.items():
        for py, name in _JSON_TYPES:
            if isinstance(value, py):
                props[key] = {"type": "number" if name == "integer" and key != "seq" else name}
                break
    return {"type": "object", "properties": props, "additionalProperties": True}


def to_ns(ts: float) -> int:
    return max(0, round(ts * 1e9))


def _stamp(ts: float) -> Timestamp:
    ns = to_ns(ts)
    return Timestamp(seconds=ns // 1_000_000_000, nanos=ns % 1_000_000_000)


def quaternion(m: list[list[float]]) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a 3x3 rotation matrix (Shepperd's method: stable for every rotation)."""
    tr = m[0][0] + m[1][1] + m[2][2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        return ((m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s, s / 4)
    if m[0][0] > m[1][1] and m[0][0] > m[2][2]:
        s = math.sqrt(1.0 + m[0][0] - m[1][1] - m[2][2]) * 2
        return (s / 4, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s, (m[2][1] - m[1][2]) / s)
    if m[1][1] > m[2][2]:
        s = math.sqrt(1.0 + m[1][1] - m[0][0] - m[2][2]) * 2
        return ((m[0][1] + m[1][0]) / s, s / 4, (m[1][2] + m[2][1]) / s, (m[0][2] - m[2][0]) / s)
    s = math.sqrt(1.0 + m[2][2] - m[0][0] - m[1][1]) * 2
    return ((m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, s / 4, (m[1][0] - m[0][1]) / s)


class McapRunWriter:
    def __init__(self, out: IO[bytes], compression: CompressionType = CompressionType.ZSTD) -> None:
        self._w = Writer(out, compression=compression)
        self._w.start(profile=PROFILE, library="mollusca-fleet (mcap python)")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.counts: dict[str, int] = {}
        self._pose_channels: dict[str, int] = {}
        self._pose_counts: dict[str, int] = {}
        self._pose_msg = PoseInFrame(frame_id=POOL_FRAME)
        self._clock: dict[str, tuple[list[float], list[float]]] = {}
        #: the last log time written per channel: a step of a robot's measured offset never makes a
        #: channel's log times go backwards
        self._last_ns: dict[int, int] = {}

    def set_clock_offsets(self, offsets: dict[str, list[tuple[float, float]]]) -> None:
        self._clock = {
            rid: ([t for t, _ in samples], [o for _, o in samples]) for rid, samples in offsets.items() if samples
        }

    def robot_time(self, robot_id: str, ts: float) -> float:
        """A robot's stamp on the server's clock: plus the offset measured last at or before it (the first
        one before any), unchanged when the robot never reported one."""
        clock = self._clock.get(robot_id)
        if clock is None:
            return ts
        times, offsets = clock
        return ts + offsets[max(0, bisect.bisect_right(times, ts) - 1)]

    def _monotonic(self, channel_id: int, ns: int) -> int:
        last = self._last_ns.get(channel_id, 0)
        if ns < last:
            return last
        self._last_ns[channel_id] = ns
        return ns

    def _proto_schema(self, cls: type[Message]) -> int:
        name = cls.DESCRIPTOR.full_name
        if name not in self._schemas:
            fds = build_file_descriptor_set(cls)
            self._schemas[name] = self._w.register_schema(
                name=name, encoding=SchemaEncoding.Protobuf, data=fds.SerializeToString()
            )
        return self._schemas[name]

    def _proto_channel(self, topic: str, cls: type[Message]) -> int:
        if topic not in self._channels:
            self._channels[topic] = self._w.register_channel(
                topic=topic, message_encoding=MessageEncoding.Protobuf, schema_id=self._proto_schema(cls)
            )
        return self._channels[topic]

    def _json_channel(self, topic: str, schema_name: str, example: dict[str, Any]) -> int:
        if topic not in self._channels:
            schema_id = self._w.register_schema(
                name=schema_name, encoding=SchemaEncoding.JSONSchema, data=orjson.dumps(json_schema_of(example))
            )
            self._channels[topic] = self._w.register_channel(
                topic=topic, message_encoding=MessageEncoding.JSON, schema_id=schema_id
            )
        return self._channels[topic]

    def _put(
        self, channel_id: int, topic: str, ts: float, data: bytes, seq: int = 0, published: float | None = None
    ) -> None:
        """``ts``: the log time (server clock); ``published``: the sender's own stamp when that differs."""
        ns = self._monotonic(channel_id, to_ns(ts))
        pub = ns if published is None else to_ns(published)
        self._w.add_message(channel_id=channel_id, log_time=ns, publish_time=pub, data=data, sequence=seq & 0xFFFFFFFF)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    # -- message kinds ------------------------------------------------------------------------------------
    def telemetry(
        self, robot_id: str, stream: str, ts: float, seq: int, payload: Any, recv_ts: float | None = None
    ) -> None:
        data = loads_json(payload)
        at = self.robot_time(robot_id, ts)
        if stream == "position" and isinstance(data, dict):
            self._pose(robot_id, at, ts, seq, data)
            return
        topic = f"/{robot_id}/{stream}"
        body = {"ts": ts, "recv_ts": recv_ts, "seq": seq, **(data if isinstance(data, dict) else {"value": data})}
        channel = self._json_channel(topic, f"fleet.{stream}", body)
        self._put(channel, topic, at, orjson.dumps(body), seq, published=ts)
        if stream == "apriltag" and isinstance(data, dict):
            self._annotations(robot_id, at, data, seq)
        elif stream == "lighthouse_geometry" and isinstance(data, dict):
            self.transforms(ts, list(data.get("base_stations") or []), [])

    def _pose(self, robot_id: str, ts: float, published: float, seq: int, data: dict[str, Any]) -> None:
        """The hot path (most of a run's messages): one reused message, one channel lookup."""
        channel_id = self._pose_channels.get(robot_id)
        if channel_id is None:
            channel_id = self._pose_channels[robot_id] = self._proto_channel(f"/{robot_id}/position", PoseInFrame)
        msg = self._pose_msg
        ns = self._monotonic(channel_id, to_ns(ts))
        msg.timestamp.seconds, msg.timestamp.nanos = divmod(ns, 1_000_000_000)
        position, orientation = msg.pose.position, msg.pose.orientation
        position.x = float(data.get("x") or 0.0)
        position.y = float(data.get("y") or 0.0)
        position.z = float(data.get("z") or 0.0)
        half_yaw = float(data.get("yaw") or 0.0) / 2
        orientation.z, orientation.w = math.sin(half_yaw), math.cos(half_yaw)
        self._w.add_message(
            channel_id=channel_id,
            log_time=ns,
            publish_time=to_ns(published),
            data=msg.SerializeToString(),
            sequence=seq & 0xFFFFFFFF,
        )
        self._pose_counts[robot_id] = self._pose_counts.get(robot_id, 0) + 1

    def transforms(self, ts: float, stations: list[dict[str, Any]], tags: list[dict[str, Any]]) -> None:
        """Base stations and wall tags as frames under ``pool`` on ``/tf`` (Foxglove's 3D panel shows them)."""
        msg = FrameTransforms()
        for st in stations:
            tf = msg.transforms.add(
                timestamp=_stamp(ts), parent_frame_id=POOL_FRAME, child_frame_id=f"base_station_{st.get('id')}"
            )
            tf.translation.x, tf.translation.y, tf.translation.z = (float(v) for v in st["position"])
            tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = quaternion(st["rotation"])
        for tag in tags:
            pose = tag.get("pose") or {}
            tf = msg.transforms.add(
                timestamp=_stamp(ts), parent_frame_id=POOL_FRAME, child_frame_id=f"tag_{tag.get('id')}"
            )
            tf.translation.x, tf.translation.y = float(pose.get("x", 0.0)), float(pose.get("y", 0.0))
            tf.translation.z = float(pose.get("z", 0.0))
            half_yaw = float(pose.get("yaw", 0.0)) / 2
            tf.rotation.z, tf.rotation.w = math.sin(half_yaw), math.cos(half_yaw)
        if msg.transforms:
            self._put(self._proto_channel("/tf", FrameTransforms), "/tf", ts, msg.SerializeToString())

    def _annotations(self, robot_id: str, ts: float, data: dict[str, Any], seq: int) -> None:
        """The detections of one frame drawn over the camera image: outline and tag id."""
        topic = f"/{robot_id}/camera/annotations"
        msg = ImageAnnotations()
        for det in data.get("detections") or []:
            corners = det.get("corners") or []
            points = msg.points.add(timestamp=_stamp(ts), type=PointsAnnotation.LINE_LOOP, thickness=2)
            for u, v in corners:
                points.points.add(x=float(u), y=float(v))
            points.outline_color.g, points.outline_color.a = 1.0, 1.0
            center = det.get("center") or [0.0, 0.0]
            text = msg.texts.add(timestamp=_stamp(ts), text=f"tag {det.get('tag_id')}", font_size=14)
            text.position.x, text.position.y = float(center[0]), float(center[1])
            text.text_color.r = text.text_color.g = text.text_color.b = text.text_color.a = 1.0
        self._put(self._proto_channel(topic, ImageAnnotations), topic, ts, msg.SerializeToString(), seq)

    def frame(self, frame: StoredFrame, jpeg: bytes) -> None:
        topic = f"/{frame.robot_id}/camera"
        at = self.robot_time(frame.robot_id, frame.ts)
        msg = CompressedImage(timestamp=_stamp(at), frame_id=f"{frame.robot_id}/camera", data=jpeg, format="jpeg")
        channel = self._proto_channel(topic, CompressedImage)
        self._put(channel, topic, at, msg.SerializeToString(), frame.frame_seq, published=frame.ts)

    def log(self, topic: str, ts: float, level: int, name: str, message: str) -> None:
        msg = Log(timestamp=_stamp(ts), level=level, name=name, message=message)  # type: ignore[arg-type]
        self._put(self._proto_channel(topic, Log), topic, ts, msg.SerializeToString())

    def command(self, row: Any) -> None:
        topic = f"/{row.robot_id}/commands"
        body = {
            "id": row.id,
            "command": row.command,
            "args": loads_json(row.args),
            "source": row.source,
            "ts": row.ts,
            "ttl_s": row.ttl_s,
            "status": row.status,
            "reason": row.reason,
        }
        self._put(self._json_channel(topic, "fleet.command", body), topic, row.ts, orjson.dumps(body))

    # -- records ----------------------------------------------------------------------------------------------
    def metadata(self, name: str, data: dict[str, str]) -> None:
        self._w.add_metadata(name=name, data=data)

    def attachment(self, name: str, media_type: str, data: bytes, ts: float) -> None:
        ns = to_ns(ts)
        self._w.add_attachment(create_time=ns, log_time=ns, name=name, media_type=media_type, data=data)

    def finish(self) -> None:
        self._w.finish()
        for robot_id, n in self._pose_counts.items():
            self.counts[f"/{robot_id}/position"] = n


def loads_json(value: Any) -> Any:
    return orjson.loads(value) if isinstance(value, str | bytes) else value
