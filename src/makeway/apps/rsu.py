"""``makeway rsu …``: the roadside unit — Framework B on a pole camera's video, EVs located on the road,
signed alerts published over zenoh and/or logged; and the hand calibration of a pole camera.

:func:`run_rsu` checks every input (video, calibration, key, segment, output folder) before the
first frame, runs the vision pipeline (:func:`makeway.pipeline.video.run_video`) and, frame by frame,
:class:`~makeway.roadside.node.RoadsideNode`. Each alert is stamped with the wall clock when it is
made (a live unit's behaviour; the video time is logged beside it), signed with the unit's key, and

* published on the road segment's zenoh key (:mod:`makeway.v2x.transport`) with ``publish``;
* written with ``out``: ``OUT/alerts.bin`` (the signed alerts back to back, each carrying the
  unit's certificate), ``OUT/alerts.jsonl`` (one line per alert, in the same order: decoded fields,
  its length in ``alerts.bin`` (``bytes``), video time, track id, road-frame position and the 1-σ
  uncertainties) and ``OUT/summary.json``.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

from makeway.atomic import atomic_path, check_writable, write_text_atomic
from makeway.errors import InputError
from makeway.v2x.message import SEQUENCE_MODULUS

__all__ = ["DEFAULT_SEGMENT", "calibrate_camera", "run_rsu"]

DEFAULT_SEGMENT = "rsu-1"


def calibrate_camera(
    points: Path,
    out: Path,
    *,
    width: int,
    height: int,
    model: str = "kannala_brandt",
    origin: tuple[float, float] | None = None,
) -> dict[str, Any]:
    """Fit a pole camera to a landmarks file (:mod:`makeway.roadside.calibrate`), write the
    calibration YAML to ``out``; its summary, the RMS reprojection error (px) and the
    leave-one-out held-out error of the landmarks (median, 95th percentile, max; metres)."""
    import numpy as np
    import yaml

    from makeway.roadside.calibrate import fit_road_camera, leave_one_out_errors, read_road_points
    from makeway.roadside.geodesy import LocalFrame

    p = read_road_points(points)
    frame = LocalFrame(origin[0], origin[1]) if origin is not None else None
    cam, rms = fit_road_camera(
        p.pixels, p.xy, width, height, model=model, origin=frame, vanishing=p.vanishing
    )
    err = leave_one_out_errors(p.pixels, p.xy, width, height, model=model, vanishing=p.vanishing)
    write_text_atomic(out, yaml.safe_dump(cam.to_dict(), sort_keys=False))
    return {
        "calibration": str(out),
        "points": len(p.pixels),
        "vanishing_points": len(p.vanishing),
        "rms_px": rms,
        "heldout_median_m": float(np.median(err)),
        "heldout_p95_m": float(np.percentile(err, 95)),
        "heldout_max_m": float(err.max()),
        **cam.summary(),
    }


#: The JSON Schema of the alerts in ``makeway rsu run --mcap``'s ``/v2x/alerts`` channel.
ALERT_SCHEMA: dict[str, Any] = {
    "title": "makeway.V2XAlert",
    "description": "A signed EV alert the roadside unit made: header (station, sequence, time), signer, "
    "the EV track's position (m, road frame; WGS-84), heading, speed and their uncertainties.",
    "type": "object",
}


def run_rsu(
    video: Path,
    calib: Path,
    key: Path,
    *,
    publish: bool = True,
    segment: str = DEFAULT_SEGMENT,
    connect: list[str] | None = None,
    listen: list[str] | None = None,
    wait_s: float = 5.0,
    rate_hz: float = 10.0,
    out: Path | None = None,
    max_frames: int | None = None,
    stride: int = 1,
    detector: str = "yolox_nano",
    classifier: str = "default",
    siren: bool = False,
    progress: bool = True,
    topic: str | None = None,
    mcap: Path | None = None,
    realtime: bool = False,
) -> dict[str, Any]:
    """Run the roadside unit over ``video`` (module docstring); the run's summary: frames, EV
    tracks reported, alerts made and published, alerts per second of wall time, and where the
    logs went. ``connect``/``listen``: zenoh loopback endpoints (default: connect to a car
    listening on ``tcp/127.0.0.1:7447``); ``wait_s``: how long to wait for a subscriber before the
    first frame (s). ``siren``: the siren flag of the alerts (a camera cannot hear it).
    ``video`` may be a robotics log (an MCAP file or a ROS 2 bag folder) with the camera ``topic``
    (default: its only camera topic); with ``mcap`` the run is also written there for Foxglove (the
    camera, the boxes, the tracks, on ``/v2x/alerts`` every alert made and on ``/roadside/evs`` the
    reported EVs as scene entities on the road). ``realtime`` plays the video as a live camera:
    frames come on the video's clock and, when the unit falls behind, the oldest waiting frame is
    dropped, never the newest (``dropped_frames``)."""
    from makeway.apps.v2x import DEFAULT_ENDPOINT
    from makeway.roadside.node import RoadsideNode, camera_location, sign_report
    from makeway.roadside.transform import read_transform_calibration
    from makeway.sense.logs import open_frame_source
    from makeway.v2x.security import load_identity
    from makeway.v2x.transport import segment_key

    if not publish and out is None:
        raise ValueError("nothing to do: give --publish and/or --out")
    if not (rate_hz > 0 and math.isfinite(rate_hz)):
        raise ValueError(f"--rate-hz must be a positive number, not {rate_hz}")
    segment_key(segment)
    video = Path(video)
    if not video.exists():
        raise InputError(video, "video not found")
    camera = read_transform_calibration(calib)
    if camera.origin is None:
        raise InputError(calib, "has no origin (lat_deg, lon_deg): alerts need WGS-84 positions")
    probe = open_frame_source(video, topic, max_frames=1)
    info = probe.info
    probe.close()
    if (info.width, info.height) != (camera.camera.width, camera.camera.height):
        raise InputError(
            calib,
            f"is for a {camera.camera.width}×{camera.camera.height} image, the video is "
            f"{info.width}×{info.height}",
        )
    identity = load_identity(key)
    if out is not None:
        check_writable(out, folder=True)
    if mcap is not None:
        check_writable(mcap, folder=False)
    track_classifier = _classifier(classifier)

    node = RoadsideNode(camera, rate_hz=rate_hz)
    unit_at = camera_location(camera)
    session = pub = None
    matched = False
    if publish:
        from makeway.v2x.transport import AlertPublisher, open_peer

        session = open_peer(listen or [], connect if connect is not None else [DEFAULT_ENDPOINT])
        pub = AlertPublisher(session, segment)
        matched = pub.wait_for_subscribers(wait_s) if wait_s > 0 else False
    rows: list[str] = []
    blobs: list[bytes] = []
    reported: set[int] = set()
    sequence = _first_sequence(key)
    made = 0
    t0 = time.perf_counter()

    def on_frame(frame: Any) -> None:
        nonlocal sequence, made
        node.update(frame)
        for report in node.due_alerts(frame.time_s):
            now = time.time()
            alert, signed = sign_report(report, identity, sequence, now, siren=siren, location=unit_at)
            sequence = (sequence + 1) % SEQUENCE_MODULUS
            made += 1
            reported.add(report.track_id)
            if pub is not None:
                pub.publish(signed)
            if out is not None or recorder is not None:
                fields = {k: v for k, v in report.to_json().items() if k != "time_s"}
                head = {**alert.to_json(), "signer": identity.signer.hex(), "bytes": len(signed)}
                row = head | {"video_time_s": round(report.time_s, 6)} | fields
            if out is not None:
                blobs.append(signed)
                rows.append(json.dumps(row, allow_nan=False))
            if recorder is not None:
                recorder.json("/v2x/alerts", report.time_s, row, "makeway.V2XAlert", ALERT_SCHEMA)
                recorder.ev_report(report)

    from makeway.pipeline.video import run_video

    recorder = None
    if mcap is not None:
        from makeway.viz.foxglove import DetectRecorder

        recorder = DetectRecorder(mcap)
    try:
        summary = run_video(
            video,
            None,
            detector=detector,
            stride=stride,
            max_frames=max_frames,
            write_video=False,
            classifier=track_classifier,
            on_frame=on_frame,
            progress=progress,
            topic=topic,
            mcap=recorder,
            realtime=realtime,
        )
    except BaseException:
        if recorder is not None:
            recorder.abort()  # nothing half-written, also when the run failed before its first frame
        raise
    finally:
        if pub is not None and session is not None:
            time.sleep(0.2)  # let the last samples leave before the session closes
            pub.close()
            session.close()
    wall = time.perf_counter() - t0
    _save_sequence(key, sequence)
    result: dict[str, Any] = {
        "video": str(video),
        "calibration": str(calib),
        "segment": segment,
        "frames": summary.frames,
        "dropped_frames": summary.dropped_frames,
        "video_seconds": summary.video_seconds,
        "wall_seconds": round(wall, 3),
        "active_ev_tracks": summary.active_ev_tracks,
        "reported_tracks": sorted(reported),
        "alerts": made,
        "alerts_per_video_second": round(made / summary.video_seconds, 3) if summary.video_seconds else 0.0,
        "alerts_per_wall_second": round(made / wall, 3) if wall > 0 else 0.0,
        "published": made if publish else 0,
        "subscriber_found": matched,
        "outputs": {} if mcap is None else {"mcap": str(mcap)},
    }
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        with atomic_path(out / "alerts.bin") as tmp:
            tmp.write_bytes(b"".join(blobs))
        write_text_atomic(out / "alerts.jsonl", "".join(r + "\n" for r in rows))
        result["outputs"] |= {
            "alerts": str(out / "alerts.bin"),
            "log": str(out / "alerts.jsonl"),
            "summary": str(out / "summary.json"),
        }
        write_text_atomic(out / "summary.json", json.dumps(result, indent=2) + "\n")
    return result


def _classifier(name: str) -> Any:
    """The per-track EV classifier (built now, so bad weights fail before the first frame)."""
    if name.strip().lower() == "none":
        return None
    from makeway.perceive.vision.ev_classifier import EVTrackClassifier, load_crop_classifier

    track_classifier = EVTrackClassifier(load_crop_classifier(name))
    getattr(track_classifier.classifier, "extractors", None)
    return track_classifier


def _first_sequence(key: Path) -> int:
    """The unit's next sequence number, from the counter ``KEY.seq`` that ``makeway v2x alert`` keeps."""
    path = Path(key).with_suffix(".seq")
    if not path.exists():
        return 1
    try:
        return (int(path.read_text(encoding="utf-8").strip()) + 1) % SEQUENCE_MODULUS
    except ValueError:
        raise InputError(path, "is not a sequence counter (one integer)") from None


def _save_sequence(key: Path, next_sequence: int) -> None:
    write_text_atomic(Path(key).with_suffix(".seq"), f"{(next_sequence - 1) % SEQUENCE_MODULUS}\n")
