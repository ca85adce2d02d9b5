"""``makeway lights``: lit emergency lights in a video or a folder of images, tracked, with their
flash frequency and (given a rig and a camera) their azimuth.

For a video: the light detector (:data:`~makeway.perceive.vision.lights.LIGHT_DETECTORS`, default
:data:`~makeway.perceive.vision.lights.REVIEW_LIGHT_DETECTOR`) runs on every frame, the
:class:`~makeway.track.lights.LightTracker` follows each light and measures its flash pattern, and the
output folder gets

* ``annotated.mp4`` — H.264, each light boxed in its colour with its track id, flash frequency and
  azimuth;
* ``lights.jsonl`` — one JSON object per frame: ``frame`` (0-based index), ``time_s`` and
  ``lights``, a list of the lights the detector saw in that frame, each with ``track_id``, ``box``
  (pixels, ``x1 y1 x2 y2``), ``colour``, ``score``, ``flash_hz`` (0.0 until an on/off cycle is
  seen), ``duty``, ``flashing`` and, with a rig, ``azimuth_deg`` / ``elevation_deg`` (vehicle frame,
  0 ahead, positive left / up; of the box centre's ray, :meth:`makeway.sense.rig.Rig.azimuth`;
  ``null`` where the lens model has no ray);
* ``summary.json`` — counts, timings, the settings.

For a folder of images each image is one frame with no tracking and no flash cue (``track_id``,
``flash_hz``, ``duty``, ``flashing`` are ``null``); annotated copies go to ``annotated/``.
Everything is written only when the run completes; a failure leaves no output folder it created.
"""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from makeway.atomic import atomic_dir, atomic_path, check_writable, removed_on_error, write_text_atomic
from makeway.errors import InputError
from makeway.messages import LightDetection
from makeway.perceive.vision.lights import REVIEW_LIGHT_DETECTOR, colour_set
from makeway.progress import progress_bar
from makeway.sense.crops import IMAGE_SUFFIXES
from makeway.sense.logs import is_log, open_frame_source
from makeway.sense.rig import Rig, load_rig
from makeway.track.lights import LightTrack, LightTracker, build_light_detector
from makeway.viz.video_writer import H264Writer

__all__ = ["LightsSummary", "lights"]

#: Box colour (BGR) per light colour.
DRAW_BGR: dict[str, tuple[int, int, int]] = {
    "blue": (255, 128, 0),
    "red": (0, 0, 255),
    "amber": (0, 170, 255),
    "white": (255, 255, 255),
}


@dataclass
class LightsSummary:
    """What :func:`lights` did (``summary.json``)."""

    source: str
    kind: str  # "video" or "images"
    out_dir: str
    detector: str
    colours: list[str]
    camera: str | None
    frames: int
    width: int
    height: int
    fps: float | None
    light_detections: int
    light_tracks: int
    flashing_tracks: list[int]
    wall_seconds: float
    ms_per_frame: float
    realtime_factor: float | None
    outputs: dict[str, str] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def _image_files(folder: Path) -> list[Path]:
    files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise InputError(folder, f"has no images ({', '.join(IMAGE_SUFFIXES)})")
    return files


def _direction(rig: Rig | None, camera: str | None, box_center: tuple[float, float]) -> dict[str, Any]:
    if rig is None or camera is None:
        return {}
    try:
        d = rig.azimuth(camera, box_center[0], box_center[1])
    except InputError:  # beyond the lens model's field
        return {"azimuth_deg": None, "elevation_deg": None}
    return {
        "azimuth_deg": round(float(d.azimuth_deg), 3),
        "elevation_deg": round(float(d.elevation_deg), 3),
    }


def _check_size(rig: Rig | None, camera: str | None, source: Path, width: int, height: int) -> None:
    if rig is None or camera is None:
        return
    cam = rig.camera(camera).camera
    if (cam.width, cam.height) != (width, height):
        raise InputError(
            source,
            f"frames are {width}×{height} but camera {camera!r} of {rig.source} is "
            f"{cam.width}×{cam.height}; use the rig camera that recorded them",
        )


def _draw(img: np.ndarray, box: Any, colour: str, text: str) -> None:
    bgr = DRAW_BGR.get(colour, (0, 255, 0))
    p1 = (int(box.x1) - 2, int(box.y1) - 2)
    p2 = (int(np.ceil(box.x2)) + 2, int(np.ceil(box.y2)) + 2)
    cv2.rectangle(img, p1, p2, bgr, 2 if "Hz" in text else 1)
    if text:
        org = (p1[0], max(10, p1[1] - 4))
        cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.4, bgr, 1, cv2.LINE_AA)


def _panel(img: np.ndarray, lines: list[str]) -> None:
    for i, line in enumerate(lines):
        org = (8, 20 + 18 * i)
        cv2.putText(img, line, org, cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(img, line, org, cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)


def _track_record(lt: LightTrack, frame: int, rig: Rig | None, camera: str | None) -> dict[str, Any]:
    return {
        "frame": frame,
        "track_id": lt.track_id,
        "box": lt.box.to_dict(),
        "colour": lt.colour,
        "score": round(float(lt.score), 4),
        "flash_hz": round(float(lt.flash_hz), 3),
        "duty": round(float(lt.duty), 3),
        "flashing": lt.flashing,
        **_direction(rig, camera, lt.box.center),
    }


def _detection_record(d: LightDetection, rig: Rig | None, camera: str | None) -> dict[str, Any]:
    return {
        "frame": d.frame,
        "track_id": None,
        "box": d.box.to_dict(),
        "colour": d.colour,
        "score": round(float(d.score), 4),
        "flash_hz": None,
        "duty": None,
        "flashing": None,
        **_direction(rig, camera, d.box.center),
    }


def _label(rec: dict[str, Any]) -> str:
    parts = [] if rec["track_id"] is None else [f"#{rec['track_id']}"]
    if rec.get("flashing"):
        parts.append(f"{rec['flash_hz']:.1f}Hz")
    if rec.get("azimuth_deg") is not None:
        parts.append(f"{rec['azimuth_deg']:+.0f}deg")
    return " ".join(parts)


def lights(
    source: str | Path,
    out: str | Path | None = None,
    *,
    rig: str | Path | None = None,
    camera: str | None = None,
    detector: str = REVIEW_LIGHT_DETECTOR,
    colours: str = "eu",
    max_frames: int | None = None,
    write_video: bool = True,
    tracker: LightTracker | None = None,
    progress: bool = True,
    topic: str | None = None,
) -> LightsSummary:
    """Find, track and describe the lit emergency lights of a video or image folder (module docstring).

    Args:
        source: a video file, a folder of images, or a robotics log (an MCAP file or a ROS 2 bag
            folder) whose camera ``topic`` is read like a video (``None``: its only camera topic).
        out: output folder (default ``makeway_out/<source name>_lights``).
        rig: rig file (YAML) or ``"default"``; with ``camera``, each light gets its azimuth. A
            ``camera`` without ``rig`` uses the shipped default rig.
        camera: camera name in the rig; the frames must have its width and height.
        detector: light detector name in the registry.
        colours: colour set (:data:`~makeway.perceive.vision.lights.COLOUR_SETS` name or colours).
        max_frames: stop after this many frames (video) or images.
        write_video: also write ``annotated.mp4`` / ``annotated/`` images.
        tracker: override the default :class:`~makeway.track.lights.LightTracker`.
        progress: show a rich progress bar.
        topic: the camera topic when ``source`` is a log.

    Raises:
        InputError: missing or unreadable source (a log: damaged, or no such camera topic), an
            empty image folder, a bad rig file, an unknown camera, frames of another size than the
            camera's, an unwritable output folder, a video that ends early (all before or without
            leaving anything half-written).
        UnknownNameError: an unknown detector.
        ValueError: an unknown colour set.
    """
    src = Path(source)
    if not src.exists():
        raise InputError(src, "not found (a video file or a folder of images is needed)")
    colour_names = colour_set(colours)
    det = build_light_detector(detector, colour_names)
    rig_obj: Rig | None = None
    if camera is not None or rig is not None:
        rig_obj = load_rig(rig if rig is not None else "default")
        if camera is None:
            raise InputError(
                rig_obj.source, f"--camera is needed with a rig; its cameras: {', '.join(rig_obj.names)}"
            )
        rig_obj.camera(camera)
    out_dir = Path(out) if out is not None else Path("makeway_out") / f"{src.stem}_lights"
    check_writable(out_dir, folder=True)
    job = _Job(src, out_dir, det, detector, colour_names, rig_obj, camera, max_frames, progress, topic)
    if src.is_dir() and not is_log(src):
        if topic is not None:
            raise InputError(
                src, "a camera topic was named, but this is not an MCAP file or a ROS 2 bag folder"
            )
        return _run_images(job, write_video)
    return _run_video(job, write_video, tracker)


@dataclass(frozen=True)
class _Job:
    """One :func:`lights` run, checked: the source, the output folder and the detector set up."""

    src: Path
    out_dir: Path
    det: Any
    detector: str
    colours: tuple[str, ...]
    rig: Rig | None
    camera: str | None
    max_frames: int | None
    progress: bool
    topic: str | None = None

    def finish(
        self,
        kind: str,
        *,
        frames: int,
        width: int,
        height: int,
        fps: float | None,
        light_detections: int,
        light_tracks: int,
        flashing_tracks: list[int],
        wall_s: float,
        realtime_factor: float | None,
        outputs: dict[str, str],
    ) -> LightsSummary:
        """The run's :class:`LightsSummary`, also written to ``out_dir/summary.json``."""
        summary = LightsSummary(
            source=str(self.src),
            kind=kind,
            out_dir=str(self.out_dir),
            detector=self.detector,
            colours=list(self.colours),
            camera=self.camera,
            frames=frames,
            width=width,
            height=height,
            fps=fps,
            light_detections=light_detections,
            light_tracks=light_tracks,
            flashing_tracks=flashing_tracks,
            wall_seconds=round(wall_s, 3),
            ms_per_frame=round(1000 * wall_s / max(frames, 1), 3),
            realtime_factor=realtime_factor,
            outputs=outputs,
        )
        summary.outputs["summary"] = str(self.out_dir / "summary.json")
        write_text_atomic(self.out_dir / "summary.json", json.dumps(summary.to_json(), indent=2) + "\n")
        return summary


def _run_video(job: _Job, write_video: bool, tracker: LightTracker | None) -> LightsSummary:
    src, out_dir, rig, camera = job.src, job.out_dir, job.rig, job.camera
    reader = open_frame_source(src, job.topic, max_frames=job.max_frames)
    info = reader.info
    try:
        _check_size(rig, camera, src, info.width, info.height)
    except InputError:
        reader.close()
        raise
    trk = tracker if tracker is not None else LightTracker()
    total = info.frame_count if info.frame_count > 0 else None
    if total is not None and job.max_frames is not None:
        total = min(total, job.max_frames)
    n_frames = n_dets = 0
    track_ids: set[int] = set()
    flashing: set[int] = set()
    outputs: dict[str, str] = {}
    with (
        removed_on_error(out_dir),
        progress_bar(f"lights {src.name}", total, enabled=job.progress) as advance,
    ):
        out_dir.mkdir(parents=True, exist_ok=True)
        writer = (
            H264Writer(out_dir / "annotated.mp4", info.fps, info.width, info.height) if write_video else None
        )
        try:
            with atomic_path(out_dir / "lights.jsonl") as tmp, tmp.open("w", encoding="utf-8") as fh:
                wall0 = time.perf_counter()
                for index, t_s, image in reader:
                    tracks = trk.update(job.det.detect(image, index), t_s, image)
                    seen = [lt for lt in tracks if lt.detected]
                    recs = [_track_record(lt, index, rig, camera) for lt in seen]
                    fh.write(
                        json.dumps(
                            {"frame": index, "time_s": round(t_s, 4), "lights": recs}, separators=(",", ":")
                        )
                        + "\n"
                    )
                    n_frames += 1
                    n_dets += len(seen)
                    track_ids.update(lt.track_id for lt in seen)
                    flashing.update(lt.track_id for lt in seen if lt.flashing)
                    if writer is not None:
                        for lt, rec in zip(seen, recs, strict=True):
                            _draw(image, lt.box, lt.colour, _label(rec))
                        n_flash = sum(1 for lt in seen if lt.flashing)
                        _panel(
                            image,
                            [f"frame {index}  t {t_s:.2f} s", f"lights {len(seen)}  flashing {n_flash}"],
                        )
                        writer.write(image)
                    advance(1)
                reader.check_complete()
                advance.finish()
                wall = time.perf_counter() - wall0
            outputs["lights"] = str(out_dir / "lights.jsonl")
            if writer is not None:
                writer.close()
                outputs["video"] = str(writer.path)
        except BaseException:
            if writer is not None:
                writer.abort()
            with contextlib.suppress(OSError):
                (out_dir / "lights.jsonl").unlink()
            raise
        finally:
            reader.close()
        video_s = n_frames / info.fps if info.fps > 0 else 0.0
        summary = job.finish(
            "video",
            frames=n_frames,
            width=info.width,
            height=info.height,
            fps=info.fps,
            light_detections=n_dets,
            light_tracks=len(track_ids),
            flashing_tracks=sorted(flashing),
            wall_s=wall,
            realtime_factor=round(video_s / wall, 3) if wall > 0 else None,
            outputs=outputs,
        )
    return summary


def _read_images(files: list[Path]) -> Iterator[tuple[int, Path, np.ndarray]]:
    for i, path in enumerate(files):
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None:
            raise InputError(path, "not a decodable image")
        yield i, path, img


def _run_images(job: _Job, write_images: bool) -> LightsSummary:
    src, out_dir, rig, camera = job.src, job.out_dir, job.rig, job.camera
    files = _image_files(src)[: job.max_frames]
    n_dets = 0
    width = height = 0
    outputs: dict[str, str] = {}
    with (
        removed_on_error(out_dir),
        progress_bar(f"lights {src.name}", len(files), enabled=job.progress, unit="images") as advance,
    ):
        out_dir.mkdir(parents=True, exist_ok=True)
        ann_ctx = atomic_dir(out_dir / "annotated") if write_images else contextlib.nullcontext()
        with (
            ann_ctx as ann_dir,
            atomic_path(out_dir / "lights.jsonl") as tmp,
            tmp.open("w", encoding="utf-8") as fh,
        ):
            wall0 = time.perf_counter()
            for i, path, image in _read_images(files):
                h, w = image.shape[:2]
                _check_size(rig, camera, path, w, h)
                width, height = max(width, w), max(height, h)
                dets = job.det.detect(image, i)
                recs = [_detection_record(d, rig, camera) for d in dets]
                fh.write(
                    json.dumps({"frame": i, "image": path.name, "lights": recs}, separators=(",", ":")) + "\n"
                )
                n_dets += len(dets)
                if ann_dir is not None:
                    for d, rec in zip(dets, recs, strict=True):
                        _draw(image, d.box, d.colour, _label(rec))
                    _panel(image, [path.name, f"lights {len(dets)}"])
                    cv2.imwrite(str(Path(ann_dir) / f"{path.stem}.jpg"), image)
                advance(1)
            advance.finish()
            wall = time.perf_counter() - wall0
        outputs["lights"] = str(out_dir / "lights.jsonl")
        if write_images:
            outputs["annotated"] = str(out_dir / "annotated")
        summary = job.finish(
            "images",
            frames=len(files),
            width=width,
            height=height,
            fps=None,
            light_detections=n_dets,
            light_tracks=0,
            flashing_tracks=[],
            wall_s=wall,
            realtime_factor=None,
            outputs=outputs,
        )
    return summary
