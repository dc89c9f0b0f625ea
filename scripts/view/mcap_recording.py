"""The run as an MCAP file Foxglove opens (``--mcap FILE``): Foxglove's message schemas,
JSON-encoded (schema encoding ``jsonschema``), written with the ``mcap`` package.

Topics (log time = the scan's time):

- ``/scan`` ``foxglove.LaserScan`` in ``base_link``: the scan's points as ranges binned by
  angle over the full circle (``sensor.max_points`` bins; an empty bin is 0, "no return")
- ``/pose`` ``foxglove.PoseInFrame`` in ``map``: the SLAM's pose (absent while not localized)
- ``/tf`` ``foxglove.FrameTransforms``: ``map`` → ``base_link``
- ``/truth`` ``foxglove.PoseInFrame``: the true pose, where known (simulator)
- ``/map`` ``foxglove.Grid`` in ``map``: the occupancy map (int8, −1 unknown, else percent)
  each time it is redrawn
- ``/stats`` (plain JSON): latency_ms, evaluations, lambda, rejection_threshold, node_added,
  loop_closed

Written to a temp file beside ``FILE`` and renamed when the run ends: an interrupted run
leaves no torn recording.
"""

from __future__ import annotations

import base64
import json
import math

import numpy as np
from mcap.writer import Writer

from swarmslam.runtime.matching.scan import binned_ranges
from swarmslam.runtime.realtime.writers import AtomicFile

_TIME = {"type": "object", "properties": {"sec": {"type": "integer", "minimum": 0},
                                          "nsec": {"type": "integer", "minimum": 0}}}
_VEC3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUAT = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
_POSE = {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}}


def _schema(title: str, **properties) -> bytes:
    return json.dumps({"title": title, "type": "object", "properties": properties}).encode()


SCHEMAS = {
    "foxglove.LaserScan": _schema(
        "foxglove.LaserScan", timestamp=_TIME, frame_id={"type": "string"}, pose=_POSE,
        start_angle={"type": "number"}, end_angle={"type": "number"},
        ranges={"type": "array", "items": {"type": "number"}},
        intensities={"type": "array", "items": {"type": "number"}}),
    "foxglove.PoseInFrame": _schema(
        "foxglove.PoseInFrame", timestamp=_TIME, frame_id={"type": "string"}, pose=_POSE),
    "foxglove.FrameTransforms": _schema(
        "foxglove.FrameTransforms", transforms={"type": "array", "items": {
            "type": "object", "properties": {
                "timestamp": _TIME, "parent_frame_id": {"type": "string"},
                "child_frame_id": {"type": "string"}, "translation": _VEC3,
                "rotation": _QUAT}}}),
    "foxglove.Grid": _schema(
        "foxglove.Grid", timestamp=_TIME, frame_id={"type": "string"}, pose=_POSE,
        column_count={"type": "integer"},
        cell_size={"type": "object", "properties": {"x": {"type": "number"},
                                                    "y": {"type": "number"}}},
        row_stride={"type": "integer"}, cell_stride={"type": "integer"},
        fields={"type": "array", "items": {"type": "object", "properties": {
            "name": {"type": "string"}, "offset": {"type": "integer"},
            "type": {"type": "integer"}}}},
        data={"type": "string", "contentEncoding": "base64"}),
}
INT8 = 2  # foxglove.NumericType
TOPICS = {"/scan": "foxglove.LaserScan", "/pose": "foxglove.PoseInFrame",
          "/tf": "foxglove.FrameTransforms", "/truth": "foxglove.PoseInFrame",
          "/map": "foxglove.Grid", "/stats": None}


def _time(stamp: float) -> dict:
    ns = max(int(round(stamp * 1e9)), 0)
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _pose(x: float, y: float, theta: float) -> dict:
    return {"position": {"x": x, "y": y, "z": 0.0},
            "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(theta / 2),
                            "w": math.cos(theta / 2)}}


def laser_ranges(points, bins: int) -> np.ndarray:
    """The scan's points (robot frame) as ranges in ``bins`` equal angle bins from −π
    (0: no point in the bin; of several, the nearest)."""
    return binned_ranges(np.arctan2(points[:, 1], points[:, 0]),
                         np.hypot(points[:, 0], points[:, 1]), bins, 0.0)


class McapRecording:
    def __init__(self, path, bins: int):
        self.bins = bins
        self.out = AtomicFile(path)
        self.writer = Writer(self.out.file)
        self.writer.start(profile="", library="swarmslam")
        schema_ids = {name: self.writer.register_schema(name, "jsonschema", data)
                      for name, data in SCHEMAS.items()}
        self.channels = {topic: self.writer.register_channel(
            topic, "json", schema_ids[kind] if kind else 0) for topic, kind in TOPICS.items()}
        self.counts = dict.fromkeys(TOPICS, 0)

    def _write(self, topic: str, stamp: float, message: dict) -> None:
        ns = max(int(round(stamp * 1e9)), 0)
        self.writer.add_message(self.channels[topic], ns, json.dumps(message).encode(), ns,
                                sequence=self.counts[topic])
        self.counts[topic] += 1

    def frame(self, tick: int, f) -> None:
        t = _time(f.stamp)
        step = 2 * math.pi / self.bins
        self._write("/scan", f.stamp, {
            "timestamp": t, "frame_id": "base_link", "pose": _pose(0.0, 0.0, 0.0),
            "start_angle": -math.pi, "end_angle": -math.pi + (self.bins - 1) * step,
            "ranges": laser_ranges(f.points, self.bins).tolist(), "intensities": []})
        if np.all(np.isfinite(f.pose)):
            x, y, theta = (float(v) for v in f.pose)
            self._write("/pose", f.stamp, {"timestamp": t, "frame_id": "map",
                                           "pose": _pose(x, y, theta)})
            p = _pose(x, y, theta)
            self._write("/tf", f.stamp, {"transforms": [{
                "timestamp": t, "parent_frame_id": "map", "child_frame_id": "base_link",
                "translation": p["position"], "rotation": p["orientation"]}]})
        if f.truth is not None:
            self._write("/truth", f.stamp, {"timestamp": t, "frame_id": "map",
                                            "pose": _pose(*(float(v) for v in f.truth))})
        self._write("/stats", f.stamp, {
            "latency_ms": f.latency_ms, "evaluations": f.evaluations,
            "lambda": f.error if math.isfinite(f.error) else None,
            "rejection_threshold": (f.rejection_threshold
                                    if math.isfinite(f.rejection_threshold) else None),
            "node_added": f.node_added, "loop_closed": f.loop_closed})

    def map(self, tick: int, stamp: float, painted, slam) -> None:
        grid, cells = painted.grid, painted.percent
        h, w = cells.shape
        self._write("/map", stamp, {
            "timestamp": _time(stamp), "frame_id": "map",
            "pose": _pose(float(grid.origin[0]), float(grid.origin[1]), 0.0),
            "column_count": w, "cell_size": {"x": grid.resolution, "y": grid.resolution},
            "row_stride": w, "cell_stride": 1,
            "fields": [{"name": "occupancy", "offset": 0, "type": INT8}],
            "data": base64.b64encode(cells.tobytes()).decode("ascii")})

    def close(self) -> None:
        self.writer.finish()
        self.out.commit()
