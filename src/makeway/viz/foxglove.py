"""Foxglove-ready MCAP logs of what a run did (issue 28, "logs out").

Every file here opens in Foxglove as it is: protobuf messages with the Foxglove schemas
(``foxglove_schemas_protobuf``; the schema record is the message's ``FileDescriptorSet``) and JSON
messages with a JSON Schema, written atomically by
:class:`~makeway.sense.log_writer.FoxgloveMcapWriter`. Frames: ``world`` (the scenario's or the
recording's planar world frame, metres), ``base_link`` (the vehicle frame: x forward, y left, z up,
origin on the ground under the rear axle) and ``camera`` (the image).

* :class:`DetectRecorder` (``makeway detect --mcap``): ``/camera/image`` (``foxglove.CompressedImage``,
  JPEG), ``/camera/annotations`` (``foxglove.ImageAnnotations``: one box per vehicle track in its EV
  state's colour, its id, class and EV state, and the lit lights), ``/perception/tracks`` (JSON:
  the ``tracks.jsonl`` line of the frame). ``makeway rsu run --mcap`` adds ``/v2x/alerts`` (JSON:
  every signed alert made) and ``/roadside/evs`` (``foxglove.SceneUpdate``: each reported EV as a box
  on the road, frame ``road``: metres, x east, y north).
* :func:`write_listen_mcap` (``makeway audio listen --mcap``): ``/siren/detection`` (JSON: the
  listener's message per hop), ``/siren/sources`` (``foxglove.SceneUpdate``: an arrow per heard
  siren along its bearing from the array centre, as long as its distance or 10 m when there is
  none), ``/array/mics`` (the capsules) and ``/tf`` (``foxglove.FrameTransform`` world → base_link
  from the ego path).
* :func:`write_simulate_mcap` (``makeway simulate --mcap``): at 20 Hz ``/tf``, ``/scene``
  (``foxglove.SceneUpdate``: the ego car, every EV — red while its lights or siren are on — and the
  lane centre line), ``/perception/belief`` (JSON: detected, confidence, distance, bearing),
  ``/decide/yield`` (JSON: the yield state, the target speed and the action) and, whenever the
  planner replans, ``/plan/path`` (``foxglove.PosesInFrame``); ``/ego/trajectory`` holds the
  driven path once.

Timestamps: a video's frame times (or a log's own stamps), the recording's or the simulation's
time, from ``start_ns``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from makeway.messages import EVState, PerceptionFrame
from makeway.sense.log_writer import FoxgloveMcapWriter

__all__ = ["DetectRecorder", "write_listen_mcap", "write_simulate_mcap"]

#: RGBA (0–1) by EV state; unjudged tracks are blue.
STATE_RGBA: dict[str, tuple[float, float, float, float]] = {
    EVState.ACTIVE.value: (1.0, 0.0, 0.0, 1.0),
    EVState.INACTIVE.value: (0.0, 0.8, 0.0, 1.0),
    EVState.WARMING_UP.value: (1.0, 0.75, 0.0, 1.0),
    "unclassified": (0.1, 0.55, 1.0, 1.0),
}
LIGHT_RGBA = {"blue": (0.0, 0.5, 1.0, 1.0), "red": (1.0, 0.0, 0.0, 1.0), "amber": (1.0, 0.67, 0.0, 1.0)}

TRACKS_SCHEMA: dict[str, Any] = {
    "title": "makeway.PerceptionFrame",
    "description": "Vehicle tracks of one camera frame: box (pixels), id, score, class, smoothed EV state.",
    "type": "object",
    "properties": {
        "index": {"type": "integer"},
        "time_s": {"type": "number"},
        "tracks": {"type": "array", "items": {"type": "object"}},
    },
}
SIREN_SCHEMA: dict[str, Any] = {
    "title": "makeway.SirenMessage",
    "description": "The siren listener's decision for one window: siren probability (raw and smoothed), "
    "level (dB SPL) and per heard siren its bearing (rad, vehicle frame, counter-clockwise from ahead), "
    "distance (m) and approaching call.",
    "type": "object",
    "properties": {
        "t_end": {"type": "number"},
        "is_siren": {"type": "boolean"},
        "probability": {"type": "number"},
        "smoothed_probability": {"type": "number"},
        "level_db_spl": {"type": ["number", "null"]},
        "sources": {"type": "array", "items": {"type": "object"}},
    },
}
BELIEF_SCHEMA: dict[str, Any] = {
    "title": "makeway.EVBelief",
    "description": "What the car believes about the nearest emergency vehicle: detected, confidence (0-1), "
    "distance (m) and bearing (rad, vehicle frame).",
    "type": "object",
    "properties": {
        "t": {"type": "number"},
        "detected": {"type": "boolean"},
        "confidence": {"type": "number"},
        "distance_m": {"type": ["number", "null"]},
        "bearing_rad": {"type": ["number", "null"]},
    },
}
YIELD_SCHEMA: dict[str, Any] = {
    "title": "makeway.YieldState",
    "description": "The yield decision: state (no_ev, ev_confirmed, moving_over, stopped_waiting, "
    "ev_passed, resuming), target speed (m/s) and the action taken.",
    "type": "object",
    "properties": {
        "t": {"type": "number"},
        "state": {"type": "string"},
        "target_speed_mps": {"type": "number"},
        "action": {"type": "string"},
    },
}


def _colour(msg: Any, rgba: Sequence[float]) -> None:
    msg.r, msg.g, msg.b, msg.a = (float(v) for v in rgba)


def _yaw_quat(q: Any, yaw: float) -> None:
    q.x, q.y, q.z, q.w = 0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)


def _transform(t_ns: int, x: float, y: float, yaw: float) -> Any:
    from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform

    tf = FrameTransform(parent_frame_id="world", child_frame_id="base_link")
    tf.timestamp.FromNanoseconds(t_ns)
    tf.translation.x, tf.translation.y = float(x), float(y)
    _yaw_quat(tf.rotation, float(yaw))
    return tf


class DetectRecorder:
    """Records ``makeway detect``'s frames into a Foxglove MCAP file (module docstring); call
    :meth:`frame` per processed frame (before the image is drawn on), then :meth:`close` — or
    :meth:`abort` to leave nothing behind. ``jpeg_quality`` sets the image compression."""

    def __init__(self, path: str | Path, *, jpeg_quality: int = 80) -> None:
        self.writer = FoxgloveMcapWriter(path)
        self.writer.json_channel("/perception/tracks", "makeway.PerceptionFrame", TRACKS_SCHEMA)
        self.quality = jpeg_quality
        self.path = Path(path)
        #: The log time (ns) of frame time 0; :func:`makeway.pipeline.video.run_video` sets it.
        self.start_ns = 0

    def json(
        self, topic: str, time_s: float, obj: Any, schema_name: str, json_schema: dict[str, Any]
    ) -> None:
        """Write a JSON message of the caller's own at frame time ``time_s`` (s)."""
        if topic not in self.writer.counts:
            self.writer.json_channel(topic, schema_name, json_schema)
        self.writer.write_json(topic, self.start_ns + int(round(time_s * 1e9)), obj)

    def ev_report(self, report: Any) -> None:
        """Draw a roadside EV report (:class:`makeway.roadside.node.EVReport`) on ``/roadside/evs``
        as a ``foxglove.SceneUpdate`` entity in the ``road`` frame (metres, x east, y north): a red
        6 × 2.3 m box along its heading, its id and speed, kept for 0.5 s."""
        from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

        t_ns = self.start_ns + int(round(report.time_s * 1e9))
        scene = SceneUpdate()
        ent = scene.entities.add()
        ent.timestamp.FromNanoseconds(t_ns)
        ent.frame_id, ent.id = "road", f"ev_{report.track_id}"
        ent.lifetime.FromNanoseconds(500_000_000)
        cube = ent.cubes.add()
        cube.pose.position.x, cube.pose.position.y, cube.pose.position.z = report.x_m, report.y_m, 1.2
        _yaw_quat(cube.pose.orientation, math.radians(90.0 - report.heading_deg))  # ENU yaw from heading
        cube.size.x, cube.size.y, cube.size.z = 6.0, 2.3, 2.4
        _colour(cube.color, (1.0, 0.1, 0.1, 0.85))
        text = ent.texts.add()
        text.pose.position.x, text.pose.position.y, text.pose.position.z = report.x_m, report.y_m, 3.5
        text.billboard, text.font_size, text.scale_invariant = True, 14.0, True
        text.text = f"EV #{report.track_id} {report.speed_mps:.1f} m/s"
        _colour(text.color, (1.0, 1.0, 1.0, 1.0))
        self.writer.write("/roadside/evs", t_ns, scene)

    def frame(
        self, t_ns: int, image_bgr: np.ndarray, frame: PerceptionFrame, lights: Sequence[Any] = ()
    ) -> None:
        from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
        from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
        from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation

        ok, jpeg = cv2.imencode(".jpg", image_bgr, [cv2.IMWRITE_JPEG_QUALITY, self.quality])
        if not ok:
            raise RuntimeError("JPEG encoding failed")
        img = CompressedImage(frame_id="camera", format="jpeg", data=jpeg.tobytes())
        img.timestamp.FromNanoseconds(t_ns)
        self.writer.write("/camera/image", t_ns, img)

        line = frame.to_json()
        ann = ImageAnnotations()
        for track in line["tracks"]:
            b = track["box"]
            rgba = STATE_RGBA.get(track["state"], STATE_RGBA["unclassified"])
            pa = ann.points.add()
            pa.timestamp.FromNanoseconds(t_ns)
            pa.type = PointsAnnotation.LINE_LOOP
            pa.thickness = 4.0 if track["state"] == EVState.ACTIVE.value else 2.0
            for x, y in ((b["x1"], b["y1"]), (b["x2"], b["y1"]), (b["x2"], b["y2"]), (b["x1"], b["y2"])):
                p = pa.points.add()
                p.x, p.y = float(x), float(y)
            _colour(pa.outline_color, rgba)
            text = ann.texts.add()
            text.timestamp.FromNanoseconds(t_ns)
            text.position.x, text.position.y = float(b["x1"]), max(0.0, float(b["y1"]) - 16.0)
            text.text = f"#{track['id']} {track['label']} {track['state'].replace('_', ' ')}"
            text.font_size = 14.0
            _colour(text.text_color, (1.0, 1.0, 1.0, 1.0))
            _colour(text.background_color, (*rgba[:3], 0.7))
        for lt in lights:
            pa = ann.points.add()
            pa.timestamp.FromNanoseconds(t_ns)
            pa.type = PointsAnnotation.LINE_LOOP
            pa.thickness = 2.0 if lt.flashing else 1.0
            box = lt.box
            for x, y in ((box.x1, box.y1), (box.x2, box.y1), (box.x2, box.y2), (box.x1, box.y2)):
                p = pa.points.add()
                p.x, p.y = float(x), float(y)
            _colour(pa.outline_color, LIGHT_RGBA.get(lt.colour, (1.0, 1.0, 1.0, 1.0)))
        ann_ts = ann.metadata.add()
        ann_ts.key, ann_ts.value = "frame_index", str(frame.frame_index)
        self.writer.write("/camera/annotations", t_ns, ann)
        self.writer.write_json("/perception/tracks", t_ns, line)

    def close(self) -> None:
        self.writer.close()

    def abort(self) -> None:
        self.writer.abort()


def write_listen_mcap(
    path: str | Path, messages: Sequence[dict[str, Any]], rec: Any, *, start_ns: int = 0
) -> dict[str, int]:
    """Write ``makeway audio listen``'s ``messages`` over the recording ``rec`` to ``path``
    (module docstring). Returns the message count per topic."""
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    with FoxgloveMcapWriter(path) as w:
        w.json_channel("/siren/detection", "makeway.SirenMessage", SIREN_SCHEMA)
        centre = np.asarray(rec.mics, dtype=np.float64).mean(axis=0)
        mics = SceneUpdate()
        ent = mics.entities.add()
        ent.timestamp.FromNanoseconds(start_ns)
        ent.frame_id, ent.id, ent.frame_locked = "base_link", "array", True
        for m in rec.mics:
            s = ent.spheres.add()
            s.pose.position.x, s.pose.position.y, s.pose.position.z = (float(v) for v in m)
            s.pose.orientation.w = 1.0
            s.size.x = s.size.y = s.size.z = 0.02
            _colour(s.color, (0.9, 0.9, 0.9, 1.0))
        w.write("/array/mics", start_ns, mics)
        for msg in messages:
            t = float(msg["t_end"])
            t_ns = start_ns + int(round(t * 1e9))
            x, y = rec.ego.position(t)
            w.write("/tf", t_ns, _transform(t_ns, float(x), float(y), float(rec.ego.heading(t))))
            w.write_json("/siren/detection", t_ns, msg)
            scene = SceneUpdate()
            ent = scene.entities.add()
            ent.timestamp.FromNanoseconds(t_ns)
            ent.frame_id, ent.id, ent.frame_locked = "base_link", "sirens", True
            ent.lifetime.FromNanoseconds(int(0.5e9))
            for k, src in enumerate(msg["sources"]):
                length = float(src["distance_m"]) if src.get("distance_m") is not None else 10.0
                a = ent.arrows.add()
                a.pose.position.x, a.pose.position.y, a.pose.position.z = (float(v) for v in centre)
                _yaw_quat(a.pose.orientation, float(src["bearing_rad"]))
                a.shaft_length, a.shaft_diameter = max(0.5, length - 1.0), 0.15
                a.head_length, a.head_diameter = 1.0, 0.5
                approaching = src.get("approaching")
                _colour(a.color, (1.0, 0.1, 0.1, 0.9) if approaching is not False else (1.0, 0.6, 0.1, 0.9))
                label = ent.texts.add()
                label.pose.position.x = float(centre[0] + length * math.cos(src["bearing_rad"]))
                label.pose.position.y = float(centre[1] + length * math.sin(src["bearing_rad"]))
                label.pose.position.z = 2.0
                label.billboard, label.font_size, label.scale_invariant = True, 14.0, True
                label.text = f"siren {k}: {math.degrees(src['bearing_rad']):.0f} deg" + (
                    f", {src['distance_m']:.0f} m" if src.get("distance_m") is not None else ""
                )
                _colour(label.color, (1.0, 1.0, 1.0, 1.0))
            w.write("/siren/sources", t_ns, scene)
        counts = dict(w.counts)
    return counts


def write_simulate_mcap(
    path: str | Path, result: Any, scenario: Any, *, rate_hz: float = 20.0
) -> dict[str, int]:
    """Write a closed-loop run (``result``: :class:`~makeway.pipeline.closed_loop.ClosedLoopResult`
    of ``scenario``) to ``path`` at ``rate_hz`` (module docstring). Returns the count per topic."""
    from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    from makeway.messages import YieldState
    from makeway.vehicle import VehicleParams

    log = result.log
    t = log["t"]
    dt = float(t[1] - t[0]) if len(t) > 1 else 0.01
    every = max(1, int(round(1.0 / (rate_hz * dt))))
    states = list(YieldState)
    params = VehicleParams()
    lane = scenario.lane

    def poses(t_ns: int, xs: np.ndarray, ys: np.ndarray) -> Any:
        msg = PosesInFrame(frame_id="world")
        msg.timestamp.FromNanoseconds(t_ns)
        heading = np.arctan2(np.gradient(ys), np.gradient(xs)) if len(xs) > 1 else np.zeros(len(xs))
        for x, y, h in zip(xs, ys, heading, strict=True):
            p = msg.poses.add()
            p.position.x, p.position.y = float(x), float(y)
            _yaw_quat(p.orientation, float(h))
        return msg

    def ns(time_s: float) -> int:
        return int(round(time_s * 1e9))

    with FoxgloveMcapWriter(path) as w:
        w.json_channel("/perception/belief", "makeway.EVBelief", BELIEF_SCHEMA)
        w.json_channel("/decide/yield", "makeway.YieldState", YIELD_SCHEMA)
        keep = slice(None, None, every)
        w.write("/ego/trajectory", 0, poses(0, log["x"][keep], log["y"][keep]))
        paths = list(result.paths)
        actions = list(result.actions)
        next_path = next_action = 0
        action = ""
        for i in range(0, len(t), every):
            ti = float(t[i])
            t_ns = ns(ti)
            while next_path < len(paths) and paths[next_path][0] <= ti + 1e-9:
                _, px, py = paths[next_path]
                w.write("/plan/path", t_ns, poses(t_ns, np.asarray(px), np.asarray(py)))
                next_path += 1
            while next_action < len(actions) and actions[next_action][0] <= ti + 1e-9:
                action = actions[next_action][2]
                next_action += 1
            w.write("/tf", t_ns, _transform(t_ns, log["x"][i], log["y"][i], log["yaw"][i]))
            scene = SceneUpdate()
            ego = scene.entities.add()
            ego.timestamp.FromNanoseconds(t_ns)
            ego.frame_id, ego.id, ego.frame_locked = "base_link", "ego", True
            cube = ego.cubes.add()
            cube.pose.position.x, cube.pose.position.z = params.length_m / 2.0 - 0.9, 0.75
            cube.pose.orientation.w = 1.0
            cube.size.x, cube.size.y, cube.size.z = params.length_m, params.width_m, 1.5
            _colour(cube.color, (0.2, 0.5, 1.0, 0.9))
            if np.isfinite(log["ev_x"][i]):
                ev = scene.entities.add()
                ev.timestamp.FromNanoseconds(t_ns)
                ev.frame_id, ev.id = "world", "ev"
                c = ev.cubes.add()
                c.pose.position.x, c.pose.position.y, c.pose.position.z = (
                    float(log["ev_x"][i]),
                    float(log["ev_y"][i]),
                    1.2,
                )
                _yaw_quat(c.pose.orientation, float(log["ev_yaw"][i]))
                c.size.x, c.size.y, c.size.z = 6.0, 2.3, 2.4
                on = log["ev_on"][i] > 0.5
                _colour(c.color, (1.0, 0.1, 0.1, 0.9) if on else (0.9, 0.9, 0.9, 0.9))
            if i == 0:
                road = scene.entities.add()
                road.timestamp.FromNanoseconds(t_ns)
                road.frame_id, road.id = "world", "lane"
                line = road.lines.add()
                line.thickness, line.scale_invariant = 0.15, False
                line.pose.orientation.w = 1.0
                for x, y in zip(lane.x_m[::5], lane.y_m[::5], strict=True):
                    p = line.points.add()
                    p.x, p.y = float(x), float(y)
                _colour(line.color, (0.8, 0.8, 0.8, 1.0))
            w.write("/scene", t_ns, scene)
            w.write_json(
                "/perception/belief",
                t_ns,
                {
                    "t": ti,
                    "detected": bool(log["belief_detected"][i] > 0.5),
                    "confidence": float(log["belief_conf"][i]),
                    "distance_m": float(log["belief_distance"][i]),
                    "bearing_rad": float(log["belief_bearing"][i]),
                },
            )
            w.write_json(
                "/decide/yield",
                t_ns,
                {
                    "t": ti,
                    "state": states[int(log["state"][i])].value,
                    "target_speed_mps": float(log["target_speed"][i]),
                    "action": action,
                },
            )
        counts = dict(w.counts)
    return counts
