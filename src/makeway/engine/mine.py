"""The data engine's per-input task: run the models, keep the hard samples with their context
(issue 28, item 3; seed 000 §3.3.2).

Seed 000 runs the EV classifier over a fleet's new logs and keeps *every* active-EV detection —
right or wrong — as a hard sample to label. Here a sample is kept when the model's probability
``p`` is at or above its decision threshold ``t`` (``reason = active``) or within ``band`` below it
(``reason = near``: the near misses, the other half of what a person should look at):

* **video** (:func:`mine_video`): vehicle detector → SORT → the crop classifier on every track's
  square crop, per processed frame. A track yields at most one sample per ``every`` processed
  frames (consecutive frames of one vehicle are near-duplicates). Context: the 224 px crop (JPEG,
  the crop-folder format the classifier trains on), the frame index, the time (s from the start of
  the video), the track id, the box (pixels);
* **images** (:func:`mine_images`): the same per image without tracking (track id −1);
* **recording** (:func:`mine_recording`): the siren network on 0.5 s windows every 0.17 s of a
  multichannel recording; a window is kept at most every ``audio_every`` windows. Context: the
  window as FLAC (all channels), its log-spectrogram as a PNG thumbnail (for the contact sheet),
  the time of the window's end.

:func:`run_input` is what a cluster worker runs: it skips an input whose folder already holds a
done-marker for the same settings (resumable), else mines it into a temporary folder that replaces
``DIR/inputs/<id>/`` only when the task succeeds (``samples.csv`` + media + ``done.json``). Bad input
comes back as a failure record (its one-line reason), never as an exception, so one bad input does
not stop the job. Each worker process loads the models once (:func:`_models`) and runs them on one
thread (the cluster scales by processes).
"""

from __future__ import annotations

import csv
import functools
import io
import json
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from makeway.atomic import atomic_dir, atomic_path, write_text_atomic
from makeway.engine.inputs import INPUT_KINDS, EngineInput
from makeway.errors import InputError

__all__ = [
    "DONE_FILE",
    "SAMPLE_COLUMNS",
    "MineConfig",
    "mine_images",
    "mine_recording",
    "mine_video",
    "run_input",
]

DONE_FILE = "done.json"
SAMPLES_FILE = "samples.csv"
#: The columns of each input's ``samples.csv`` (and of the job's ``samples.csv``).
SAMPLE_COLUMNS = (
    "input",
    "kind",
    "media",
    "probability",
    "threshold",
    "reason",
    "frame",
    "time_s",
    "track",
    "box",
)


@dataclass(frozen=True)
class MineConfig:
    """What the mining tasks run, and how hard samples are chosen (module docstring).

    ``classifier`` is a crop classifier name or file (``load_crop_classifier``), ``threshold`` its
    decision threshold (``None``: its own), ``band`` the near-threshold band below it; ``detector`` /
    ``model`` / ``score_threshold`` the vehicle detector; ``stride`` processes every N-th frame;
    ``every`` is the spacing of one track's samples in processed frames; ``siren_model`` the siren
    network (``None``: the shipped one), ``siren_threshold`` its threshold (``None``: its own),
    ``audio_every`` the spacing of kept windows; ``crop_size`` / ``margin`` the saved crops (px,
    context per side).
    """

    classifier: str = "default"
    threshold: float | None = None
    band: float = 0.2
    detector: str = "yolox_nano"
    model: str | None = None
    score_threshold: float = 0.3
    stride: int = 1
    every: int = 10
    siren_model: str | None = None
    siren_threshold: float | None = None
    audio_every: int = 3
    crop_size: int = 224
    margin: float = 0.1

    def __post_init__(self) -> None:
        if not 0.0 <= self.band <= 1.0:
            raise ValueError(f"band must lie in [0, 1], got {self.band}")
        if self.threshold is not None and not 0.0 <= self.threshold <= 1.0:
            raise ValueError(f"threshold must lie in [0, 1], got {self.threshold}")
        if self.stride < 1 or self.every < 1 or self.audio_every < 1:
            raise ValueError("stride, every and audio_every must be >= 1")

    def key(self) -> str:
        """A digest of the settings: a done-marker of other settings does not count as done."""
        import hashlib

        return hashlib.sha256(json.dumps(asdict(self), sort_keys=True).encode()).hexdigest()[:16]


def _single_thread() -> None:
    """One thread per worker process for OpenCV and BLAS (the cluster scales by processes)."""
    import cv2

    cv2.setNumThreads(1)
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")


@functools.lru_cache(maxsize=4)
def _vision_models(
    classifier: str, detector: str, model: str | None, score_threshold: float
) -> tuple[Any, Any]:
    from makeway.perceive.vision.detectors import DETECTORS
    from makeway.perceive.vision.ev_classifier import load_crop_classifier

    _single_thread()
    det = DETECTORS[detector](model, score_threshold=score_threshold, class_agnostic=True, num_threads=1)
    clf = load_crop_classifier(classifier, num_threads=1)
    return det, clf


@functools.lru_cache(maxsize=2)
def _siren_model(path: str | None, threshold: float | None) -> Any:
    from makeway.perceive.audio.siren_model import SirenModel

    _single_thread()
    return SirenModel(path, threads=1, threshold=threshold, localizer=False, ranger=False)


def _models(config: MineConfig) -> tuple[Any, Any]:
    return _vision_models(config.classifier, config.detector, config.model, config.score_threshold)


def _reason(p: float, thr: float, band: float) -> str | None:
    if p >= thr:
        return "active"
    if p >= thr - band:
        return "near"
    return None


def _write_jpeg(path: Path, image: np.ndarray) -> None:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), image, [cv2.IMWRITE_JPEG_QUALITY, 92]):
        raise OSError(f"{path}: OpenCV could not write this image")


def _box_text(box: Any) -> str:
    return " ".join(f"{v:.1f}" for v in (box.x1, box.y1, box.x2, box.y2))


def mine_video(inp: EngineInput, config: MineConfig, folder: Path) -> list[dict[str, Any]]:
    """Hard samples of a video (or its frame range ``[start, end)``): crops written under
    ``folder/crops/``; returns one dict per sample (:data:`SAMPLE_COLUMNS`, ``media`` relative to
    ``folder``).

    Raises:
        InputError: the video cannot be opened or ends well before its stated length (truncated).
    """
    from makeway.sense.video import VideoReader

    limit = None if inp.end is None else -(-inp.end // config.stride)
    # One decoder thread, as the models run on one: a worker owns one core of the cluster.
    with VideoReader(inp.path, stride=config.stride, max_frames=limit, threads=1) as reader:
        samples, processed = _mine_frames(inp, config, folder, reader, "crops")
    if processed == 0:
        raise InputError(inp.path, f"no frames in the range @{inp.start}:{inp.end or ''}")
    return samples


def mine_log(inp: EngineInput, config: MineConfig, folder: Path) -> list[dict[str, Any]]:
    """Hard samples of a robotics log (an MCAP file or a ROS 2 bag folder,
    :mod:`makeway.sense.logs`): every camera topic is mined as a video (crops under
    ``folder/crops/<topic>/``, ``frame`` the message index on that topic) and every audio topic
    with its array description as a recording (snippets under ``folder/audio/<topic>/``).

    Raises:
        InputError: the log cannot be read, or holds neither a camera nor an audio topic.
    """
    from makeway.sense.logs import LogFrameReader, open_log

    with open_log(inp.path) as log:
        topics = log.topics()
    cameras = sorted(t for t, i in topics.items() if i.kind == "camera")
    audios = sorted(t for t, i in topics.items() if i.kind == "audio")
    if not cameras and not audios:
        found = ", ".join(f"{t} ({i.kind})" for t, i in sorted(topics.items())) or "none"
        raise InputError(inp.path, f"holds no camera or audio topic to mine (topics: {found})")
    samples: list[dict[str, Any]] = []
    for topic in cameras:
        with LogFrameReader(inp.path, topic, stride=config.stride) as reader:
            samples += _mine_frames(inp, config, folder, reader, f"crops/{_topic_folder(topic)}")[0]
    for topic in audios:
        from makeway.sense.logs import read_log_recording

        rec = read_log_recording(inp.path, topic)
        samples += _mine_audio(inp, config, folder, rec, f"audio/{_topic_folder(topic)}")
    samples.sort(key=lambda s: -float(s["probability"]))
    return samples


def _topic_folder(topic: str) -> str:
    """A topic name as one folder name (``/camera/front/image`` → ``camera_front_image``)."""
    return "_".join(p for p in topic.split("/") if p) or "root"


def _mine_frames(
    inp: EngineInput, config: MineConfig, folder: Path, reader: Any, prefix: str
) -> tuple[list[dict[str, Any]], int]:
    """Detect, track and classify the frames of ``reader`` (``(index, time_s, image)``), keeping
    the tracks whose EV probability is active or near the threshold; crops go under
    ``folder/prefix``. Returns the samples and the number of frames processed."""
    from makeway.perceive.vision.crops import crops_for_tracks, square_crop
    from makeway.perceive.vision.detectors import Detector
    from makeway.track.sort import Sort

    det, clf = _models(config)
    thr = float(config.threshold if config.threshold is not None else getattr(clf, "threshold", 0.5))
    sort = Sort()
    last_kept: dict[int, int] = {}
    samples: list[dict[str, Any]] = []
    processed = 0
    for index, t_s, image in reader:
        if index < inp.start:
            continue
        if inp.end is not None and index >= inp.end:
            break
        tracks = sort.update(Detector.to_detections(det.detect_arrays(image)))
        if tracks:
            crops, kept = crops_for_tracks(
                image, [t.box for t in tracks], margin=config.margin, size=clf.input_size
            )
            probs = clf.predict_proba(crops).tolist() if len(kept) else []
            for i, p in zip(kept.tolist(), probs, strict=True):
                tr = tracks[i]
                why = _reason(float(p), thr, config.band)
                if why is None or processed - last_kept.get(tr.track_id, -config.every) < config.every:
                    continue
                crop = square_crop(image, tr.box, margin=config.margin, size=config.crop_size)
                if crop is None:
                    continue
                last_kept[tr.track_id] = processed
                media = f"{prefix}/t{tr.track_id}_f{index:06d}.jpg"
                _write_jpeg(folder / media, crop)
                samples.append(
                    _sample(inp, media, float(p), thr, why, index, t_s, tr.track_id, _box_text(tr.box))
                )
        processed += 1
    reader.check_complete()
    return samples, processed


def _sample(
    inp: EngineInput,
    media: str,
    p: float,
    thr: float,
    reason: str,
    frame: int | None,
    t_s: float | None,
    track: int | None,
    box: str = "",
) -> dict[str, Any]:
    return {
        "input": inp.name,
        "kind": inp.kind,
        "media": media,
        "probability": round(p, 6),
        "threshold": round(thr, 6),
        "reason": reason,
        "frame": "" if frame is None else frame,
        "time_s": "" if t_s is None else round(float(t_s), 3),
        "track": "" if track is None else track,
        "box": box,
    }


def mine_images(inp: EngineInput, config: MineConfig, folder: Path) -> list[dict[str, Any]]:
    """Hard samples of a folder of road images, each image on its own (no tracking): every vehicle
    box the detector finds is a crop for the classifier. An image OpenCV cannot read is skipped
    (counted in the returned list's absence; the folder fails only when none is readable).

    Raises:
        InputError: no image of the folder can be read.
    """
    import cv2

    from makeway.perceive.vision.crops import crops_for_tracks, square_crop
    from makeway.sense.crops import IMAGE_SUFFIXES

    det, clf = _models(config)
    thr = float(config.threshold if config.threshold is not None else getattr(clf, "threshold", 0.5))
    files = sorted(
        p for p in inp.path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith(".")
    )
    samples: list[dict[str, Any]] = []
    readable = 0
    for k, path in enumerate(files):
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None or image.size == 0:
            continue
        readable += 1
        boxes = [d.box for d in det.detect(image)]
        if not boxes:
            continue
        crops, kept = crops_for_tracks(image, boxes, margin=config.margin, size=clf.input_size)
        probs = clf.predict_proba(crops).tolist() if len(kept) else []
        for i, p in zip(kept.tolist(), probs, strict=True):
            why = _reason(float(p), thr, config.band)
            crop = square_crop(image, boxes[i], margin=config.margin, size=config.crop_size)
            if why is None or crop is None:
                continue
            media = f"crops/{path.stem}_d{i}.jpg"
            _write_jpeg(folder / media, crop)
            samples.append(_sample(inp, media, float(p), thr, why, k, None, -1, _box_text(boxes[i])))
    if readable == 0:
        raise InputError(inp.path, "no image in this folder can be read")
    return samples


def spectrogram_thumbnail(window: np.ndarray, sample_rate: int, size: int = 224) -> np.ndarray:
    """A BGR picture of one audio window's log-magnitude spectrogram (first channel), 0 Hz at the
    bottom up to 4 kHz (where sirens sound), ``size``×``size`` px: what the contact sheet shows."""
    import cv2

    x = np.asarray(window[0], dtype=np.float64)
    n_fft, hop = 512, 128
    if len(x) < n_fft:
        x = np.pad(x, (0, n_fft - len(x)))
    frames = np.lib.stride_tricks.sliding_window_view(x, n_fft)[::hop] * np.hanning(n_fft)
    spec = np.abs(np.fft.rfft(frames, axis=1)).T
    top = max(2, int(4000 * n_fft / sample_rate))
    db = 20 * np.log10(spec[:top] + 1e-9)
    db = np.clip((db - (db.max() - 60.0)) / 60.0, 0.0, 1.0)
    img = (255 * db[::-1]).astype(np.uint8)
    img = cv2.resize(img, (size, size), interpolation=cv2.INTER_LINEAR)
    return cv2.applyColorMap(img, cv2.COLORMAP_MAGMA)


def mine_recording(inp: EngineInput, config: MineConfig, folder: Path) -> list[dict[str, Any]]:
    """Hard samples of a multichannel recording: windows whose siren probability is active or near
    the threshold, as FLAC snippets under ``folder/audio/`` with a spectrogram PNG beside each.

    Raises:
        InputError: the recording is malformed, its array or rate is not the model's, or it is
            shorter than one window.
    """
    from makeway.sense.recording import read_recording

    return _mine_audio(inp, config, folder, read_recording(inp.path), "audio")


def _mine_audio(
    inp: EngineInput, config: MineConfig, folder: Path, rec: Any, prefix: str
) -> list[dict[str, Any]]:
    """The siren windows of the recording ``rec`` that are active or near the threshold, as FLAC
    snippets (with spectrogram JPEGs) under ``folder/prefix``."""
    import soundfile as sf

    from makeway.perceive.audio.windows import HOP_S, WINDOW_S, window_starts

    net = _siren_model(config.siren_model, config.siren_threshold)
    net.check_array(rec.mics, rec.sample_rate, inp.path)
    sr = int(rec.sample_rate)
    win = round(WINDOW_S * sr)
    starts = window_starts(rec.n_samples, sr, WINDOW_S, HOP_S)
    if len(starts) == 0:
        raise InputError(inp.path, f"is {rec.duration_s:.3g} s long, shorter than one {WINDOW_S:g} s window")
    audio = np.asarray(rec.audio)
    thr = float(net.threshold)
    probs: list[float] = []
    for b in range(0, len(starts), 32):
        batch = np.stack([audio[s : s + win].T for s in starts[b : b + 32]])
        probs += np.asarray(net.predict(batch, rec.full_scale_db_spl).prob, dtype=np.float64).tolist()
    samples: list[dict[str, Any]] = []
    last = -config.audio_every
    for k, (s, p) in enumerate(zip(starts.tolist(), probs, strict=True)):
        why = _reason(p, thr, config.band)
        if why is None or k - last < config.audio_every:
            continue
        last = k
        window = audio[s : s + win].T
        t_end = (s + win) / sr
        media = f"{prefix}/w{k:05d}.flac"
        target = folder / media
        target.parent.mkdir(parents=True, exist_ok=True)
        sf.write(str(target), window.T, sr, format="FLAC", subtype="PCM_24")
        _write_jpeg(folder / f"{prefix}/w{k:05d}.jpg", spectrogram_thumbnail(window, sr))
        samples.append(_sample(inp, media, p, thr, why, k, t_end, None))
    return samples


def _csv_text(rows: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(SAMPLE_COLUMNS), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buf.getvalue()


def read_done(folder: Path, key: str) -> dict[str, Any] | None:
    """The done-marker of an input folder when it was written with settings ``key``, else ``None``."""
    try:
        done = json.loads((folder / DONE_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return done if isinstance(done, dict) and done.get("config") == key else None


def run_input(inp: EngineInput, config: MineConfig, inputs_dir: str | Path) -> dict[str, Any]:
    """Mine one input into ``inputs_dir/<input id>/`` (module docstring); returns its record:
    ``input``, ``id``, ``kind``, ``status`` (``done``, ``skipped`` — finished earlier — or
    ``failed``), ``samples``, ``seconds`` (the task's wall time), ``cpu_s`` (the CPU time of the
    worker process meanwhile: below ``seconds`` when the machine is shared), ``worker_pid`` and, for a
    failure, ``error`` (one line)."""
    folder = Path(inputs_dir) / inp.input_id
    key = config.key()
    base = {"input": inp.name, "id": inp.input_id, "kind": inp.kind, "worker_pid": os.getpid()}
    earlier = read_done(folder, key)
    if earlier is not None:
        return {
            **base,
            "status": "skipped",
            "samples": earlier.get("samples", 0),
            "seconds": 0.0,
            "cpu_s": 0.0,
        }
    t0, c0 = time.perf_counter(), time.process_time()

    def clock() -> dict[str, float]:
        return {"seconds": time.perf_counter() - t0, "cpu_s": time.process_time() - c0}

    try:
        with atomic_dir(folder) as stage:
            samples = INPUT_KINDS[inp.kind].mine(inp, config, stage)
            write_text_atomic(stage / SAMPLES_FILE, _csv_text(samples))
            spent = clock()
            seconds = spent["seconds"]
            done = {
                "input": inp.name,
                "kind": inp.kind,
                "config": key,
                "samples": len(samples),
                "seconds": seconds,
            }
            with atomic_path(stage / DONE_FILE) as tmp:
                tmp.write_text(json.dumps(done, indent=1) + "\n", encoding="utf-8")
    except InputError as exc:
        return {**base, "status": "failed", "samples": 0, **clock(), "error": str(exc)}
    except (OSError, ValueError, RuntimeError) as exc:  # a decoder or a library giving up on the file
        msg = f"{inp.path}: {type(exc).__name__}: {exc}".splitlines()[0]
        return {**base, "status": "failed", "samples": 0, **clock(), "error": msg}
    return {**base, "status": "done", "samples": len(samples), **spent}


def read_samples(folder: Path) -> list[dict[str, str]]:
    """The rows of an input folder's ``samples.csv`` (empty when it has none)."""
    path = folder / SAMPLES_FILE
    if not path.is_file():
        return []
    with path.open(newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))
